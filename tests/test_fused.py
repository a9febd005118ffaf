"""The fused model (abrdf_jax.prior: reconstruct_fused, evidence, fitting): limits, gradients,
variance and its calibration. Synthetic data only (float64, conftest)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import abrdf_jax as aj
from abrdf_jax import prior as P
from abrdf_jax.prior import _fused as F
from abrdf_jax._rbf import rbf_interpolate

F64 = jnp.float64
EPS = 1e-6


def _tables(rng, n, r):
    """``n`` positive tables whose logs are ``a + B c`` (rank ``r``) plus a little noise."""
    ti, pi_, tv, pv = aj.pair_grid()
    a = -1.0 + 0.3 * np.cos(np.deg2rad(ti)) + 0.2 * np.cos(np.deg2rad(pi_ - pv))
    b = rng.normal(0, 0.3, (6561, r)) * np.cos(np.deg2rad(tv))[:, None]
    c = rng.normal(size=(n, 3, r))
    log_x = a[None, None] + np.einsum("pr,ncr->ncp", b, c) + 0.02 * rng.normal(size=(n, 3, 6561))
    x = np.exp(log_x) / np.cos(np.deg2rad(tv))
    return np.moveaxis(x, 1, -1).reshape(n, 81, 81, 3)


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(7)
    tables = _tables(rng, 10, 4)
    prior = P.train_prior(tables[:8], k=5, eps=EPS, dtype=F64)
    cfg = aj.Config(budget="iso102")
    meas = aj.sample(
        jnp.asarray(tables[9]), cfg, aj.Params.default(cfg, dtype=F64), as_measurements=True
    )
    return prior, meas, tables[9]


def _hyper(**kw):
    base = dict(sigma_p=1.0, sigma_k=0.3, sigma_n=0.1, coords="onion", kernel="gaussian")
    return P.FusedHyper.create(**{**base, **kw}, dtype=F64)


def test_no_kernel_is_the_prior_ridge_projection(setup):
    """σ_k → 0: the prior-only model with λ = σ_n² / σ_p²."""
    prior, meas, _ = setup
    h = _hyper(sigma_k=1e-7, sigma_p=2.0, sigma_n=0.3)
    fused = P.reconstruct_fused(meas, prior, h, reference="linear")
    ridge = P.reconstruct_prior(meas, prior, lam=0.3**2 / 2.0**2)
    np.testing.assert_allclose(fused, ridge, rtol=1e-6, atol=1e-9)


def test_no_prior_is_a_kernel_interpolant(setup):
    """σ_p → 0: a Gaussian-kernel (RBF) interpolant of the mapped residual, smoothing σ_n²/σ_k²."""
    prior, meas, _ = setup
    widths = (0.4, 0.7)
    h = _hyper(sigma_p=1e-7, sigma_k=0.5, sigma_n=0.05, widths=widths)
    mean, var, _ = F.fused_mapped(meas, prior, h, return_variance=True)
    basis = F.fused_basis(prior, meas)
    s, n = meas.t.shape
    r = F.residuals(prior, basis, meas.y.reshape(s * n, 3))
    keep = np.flatnonzero(np.asarray(meas.mask).reshape(-1))
    wi, wv = aj.slice_directions(meas.t, meas.pairs, jnp.deg2rad(15.0))
    coords = aj.pair_coordinates(wi.reshape(-1, 3), wv.reshape(-1, 3), "onion")[keep]
    gi, gv = F.ubo_target_vectors(F64)
    grid = aj.pair_coordinates(gi, gv, "onion")
    w4 = jnp.asarray([widths[0], widths[1], widths[0], widths[1]])
    rbf = rbf_interpolate(coords, r[keep], grid, w4, "gaussian", reg=0.05**2 / 0.5**2, degree=-1)
    expect = rbf + prior.mean[:, None]
    np.testing.assert_allclose(mean.reshape(-1, 3), expect, rtol=1e-6, atol=1e-8)
    assert np.all(np.asarray(var) >= 0)


def test_log_marginal_likelihood_oracle_and_gradients(setup):
    """The Woodbury evidence equals the dense Gaussian log-density; its gradients check."""
    prior, meas, _ = setup
    h = _hyper()
    lml, count = F.evidence(meas, prior, h)
    basis = F.fused_basis(prior, meas)
    s, n = meas.t.shape
    keep = np.flatnonzero(np.asarray(meas.mask).reshape(-1))
    r = F.residuals(prior, basis, meas.y.reshape(s * n, 3))[keep]
    x = F.sample_features(h, meas, jnp.deg2rad(15.0))[keep]
    q = basis.components[keep]
    cov = q @ q.T + 0.09 * P.covariance(h, x, x) + 0.01 * jnp.eye(len(keep))
    dense = sum(
        jax.scipy.stats.multivariate_normal.logpdf(r[:, c], jnp.zeros(len(keep)), cov)
        for c in range(3)
    )
    np.testing.assert_allclose(lml, dense, rtol=1e-9)
    assert int(count) == 3 * len(keep)
    params, static = eqx.partition(_hyper(coords="halfdiff", kernel="matern52"), eqx.is_array)

    def f(p):
        return F.evidence(meas, prior, eqx.combine(p, static))[0]

    check_grads(f, (params,), order=1, modes=("rev",), atol=1e-4, rtol=1e-4, eps=1e-5)


def test_variance_is_non_negative_and_below_the_prior(setup):
    prior, meas, _ = setup
    h = _hyper(coords="halfdiff", kernel="matern32")
    _, var = P.reconstruct_fused(meas, prior, h, return_variance=True)
    prior_var = 1.0 * np.sum(np.asarray(prior.components) ** 2, -1) + 0.3**2
    v = np.asarray(var)[..., 0].reshape(-1)
    assert v.min() >= 0 and np.all(v <= prior_var * (1 + 1e-9))
    assert v.mean() < 0.9 * prior_var.mean()  # the samples explain something


def test_calibrated_on_a_draw_of_the_model(setup):
    """Draws from the fused prior itself: the truth lies in the ±1σ / ±2σ bands about 68 % / 95 %
    of the time (latent variance; the noise is part of the samples only)."""
    prior, meas, _ = setup
    h = _hyper(sigma_p=0.5, sigma_k=0.4, sigma_n=0.05, widths=(0.3, 0.5))
    rng = np.random.default_rng(3)
    basis = F.fused_basis(prior, meas)
    keep = np.flatnonzero(np.asarray(meas.mask).reshape(-1))
    sub = rng.choice(6561, 400, replace=False)
    x_s = F.sample_features(h, meas, jnp.deg2rad(15.0))[keep]
    x_g = F.grid_features(h, F64)[sub]
    x = jnp.concatenate([x_s, x_g])
    q = jnp.concatenate([basis.components[keep], prior.components[sub]])
    cov = 0.25 * q @ q.T + 0.16 * P.covariance(h, x, x)
    chol = np.linalg.cholesky(np.asarray(cov) + 1e-9 * np.eye(len(x)))
    inside1 = inside2 = total = 0
    s, n = meas.t.shape
    for _ in range(12):
        f = chol @ rng.normal(size=(len(x), 3))
        mapped_s = f[: len(keep)] + np.asarray(basis.mean[keep])[:, None]
        mapped_s = mapped_s + 0.05 * rng.normal(size=mapped_s.shape)
        ref_s, cos_s = np.asarray(basis.reference[keep]), np.asarray(basis.cos_v[keep])
        y = P.inverse_log_relative(mapped_s, ref_s[:, None], cos_s[:, None], prior.eps)
        y_full = np.zeros((s * n, 3))
        y_full[keep] = y
        m = meas.replace(y=jnp.asarray(y_full.reshape(s, n, 3)))
        mean, var, _ = F.fused_mapped(m, prior, h, return_variance=True)
        truth = f[len(keep) :] + np.asarray(prior.mean[sub])[:, None]
        z = np.abs(truth - np.asarray(mean).reshape(-1, 3)[sub]) / np.sqrt(
            np.asarray(var).reshape(-1, 3)[sub]
        )
        inside1, inside2, total = inside1 + np.sum(z < 1), inside2 + np.sum(z < 2), total + z.size
    assert abs(inside1 / total - 0.683) < 0.07
    assert abs(inside2 / total - 0.954) < 0.04


def test_band_contains_the_mean_and_is_ordered(setup):
    prior, meas, _ = setup
    h = _hyper()
    table, var = P.reconstruct_fused(meas, prior, h, return_variance=True)
    lo, hi = P.fused_band(prior, table, var, 2.0)
    wide = P.fused_coverage(prior, table, var, table, 2.0)
    assert float(wide) == pytest.approx(1.0)
    assert np.all(np.asarray(lo) <= np.asarray(table) + 1e-12)
    assert np.all(np.asarray(table) <= np.asarray(hi) + 1e-12)


def test_evidence_fit_raises_the_evidence(setup):
    prior, meas, _ = setup
    h0 = _hyper(sigma_k=0.05, sigma_n=0.5)
    h1 = P.fit_evidence(meas, prior, h0, steps=30, lr=0.1, tau=10.0)
    assert F.evidence(meas, prior, h1)[0] > F.evidence(meas, prior, h0)[0]
    batch = aj.stack_measurements([meas, meas])
    hb = P.fit_evidence(batch, prior, h0, steps=30, lr=0.1, tau=10.0)
    np.testing.assert_allclose(hb.log_sigma_n[0], h1.log_sigma_n, rtol=1e-6)
    rec = P.reconstruct_fused(batch, prior, hb)
    np.testing.assert_allclose(rec[1], P.reconstruct_fused(meas, prior, h1), rtol=1e-6)


def test_population_fit_loss_is_the_held_out_error_and_falls(setup):
    """``fit_population``'s first loss is the mean ΔE76 of the fused reconstructions at the start
    (computed here the direct way, the basis inside each reconstruction); it keeps the best."""
    from abrdf_jax.metrics import delta_e76

    prior, one, _ = setup
    tables = _tables(np.random.default_rng(8), 4, 4)
    cfg = aj.Config(budget="iso102")
    params = aj.Params.default(cfg, dtype=F64)
    meas = aj.stack_measurements(
        [aj.sample(jnp.asarray(t), cfg, params, as_measurements=True) for t in tables]
    )
    h0 = _hyper(sigma_k=0.05, sigma_n=0.5)
    bases = F.fused_bases(prior, meas)
    np.testing.assert_allclose(
        P.reconstruct_fused(meas, prior, h0, basis=bases),
        P.reconstruct_fused(meas, prior, h0),
        rtol=1e-12,
    )
    with pytest.raises(aj.InputError, match="basis: mean of shape"):
        P.reconstruct_fused(meas, prior, h0, basis=F.fused_basis(prior, one))  # not stacked
    direct = float(
        np.mean([delta_e76(r, t) for r, t in zip(P.reconstruct_fused(meas, prior, h0), tables)])
    )
    h, losses = P.fit_population(tables, meas, h0, steps=3, lr=0.2, prior=prior)
    assert len(losses) == 3 and np.all(np.isfinite(losses)) and min(losses) < losses[0]
    np.testing.assert_allclose(losses[0], direct, rtol=1e-6)
    rec = P.reconstruct_fused(meas, prior, h)  # the kept parameters are the best step's
    got = float(np.mean([delta_e76(r, t) for r, t in zip(rec, tables)]))
    np.testing.assert_allclose(got, min(losses), rtol=1e-6)


def test_rescaling_keeps_the_mean_and_fits_the_amplitude(setup):
    prior, meas, _ = setup
    h = _hyper()
    h2 = P.fused_rescaled(meas, prior, h)
    t1, v1 = P.reconstruct_fused(meas, prior, h, return_variance=True)
    t2, v2 = P.reconstruct_fused(meas, prior, h2, return_variance=True)
    np.testing.assert_allclose(t1, t2, rtol=1e-8)
    scale = float(np.exp(2 * (h2.log_sigma_p - h.log_sigma_p)))
    np.testing.assert_allclose(v2, scale * np.asarray(v1), rtol=1e-8, atol=1e-14)
    # the amplitude is the evidence's maximum along the common scale
    lml = [
        F.evidence(
            meas,
            prior,
            eqx.tree_at(
                lambda x: (x.log_sigma_p, x.log_sigma_k, x.log_sigma_n),
                h2,
                (h2.log_sigma_p + d, h2.log_sigma_k + d, h2.log_sigma_n + d),
            ),
        )[0]
        for d in (-0.01, 0, 0.01)
    ]
    assert lml[1] > lml[0] and lml[1] > lml[2]


def test_bad_hyper_parameters_are_refused():
    with pytest.raises(aj.InputError, match="coords"):
        P.FusedHyper.create(coords="polar")
    with pytest.raises(aj.InputError, match="> 0"):
        P.FusedHyper.create(sigma_n=0.0)
    with pytest.raises(aj.InputError, match="widths"):
        P.FusedHyper.create(widths=(1.0,), coords="onion")
