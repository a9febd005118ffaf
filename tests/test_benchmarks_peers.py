"""The benchmarks' own peers are right: the PCA prior (``benchmarks/pca_peer.py``) and the analytic
model fit (``benchmarks/analytic_peer.py``) of the speed/accuracy suite.

Here ``benchmarks/`` is the code under test, not an oracle: nothing in the package is checked against
it (the package's oracle is ``tests/scipy_oracle.py``). These are not smoke runs either (that is
``test_benchmarks_smoke.py``): they check properties a peer must have for the suite's comparison to
be fair (a training material is rebuilt from its own samples, a known GGX is recovered). No shared
data needed: the package's analytic materials serve as the database and as the known models.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax.materials import GGX, dense_table
from benchmarks.analytic_peer import fit_analytic, reconstruct_analytic
from abrdf_jax.prior import inverse_log_relative, log_relative
from benchmarks.pca_peer import fit_pca_prior, flat_samples, reconstruct_pca

F64 = jnp.float64


def _ggx_family(n, seed=0):
    """``n`` GGX materials (isotropic and anisotropic, coloured) stacked into one module."""
    r = np.random.default_rng(seed)
    mats = [
        GGX(
            diffuse=r.uniform(0.02, 0.6, 3),
            specular_f0=r.uniform(0.02, 0.9, 3),
            alpha_x=r.uniform(0.05, 0.5),
            alpha_y=r.uniform(0.05, 0.5),
            rotation=r.uniform(0, np.pi),
        )
        for _ in range(n)
    ]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *mats)


@pytest.fixture(scope="module")
def database():
    """Eight GGX materials: dense tables and exact aniso204 samples (float64), one compile each."""
    mats = _ggx_family(8)
    cfg = aj.Config(budget="aniso204")
    p = aj.Params.default(cfg, dtype=F64)
    meas = jax.jit(jax.vmap(lambda m: aj.sample(m, cfg, p, as_measurements=True)))(mats)
    ti, pi_, tv, pv = (np.deg2rad(a) for a in aj.pair_grid())
    wi, wv = (
        aj.to_vector(jnp.asarray(ti), jnp.asarray(pi_)),
        aj.to_vector(jnp.asarray(tv), jnp.asarray(pv)),
    )
    tables = np.asarray(jax.jit(jax.vmap(lambda m: m(wi, wv).reshape(81, 81, 3)))(mats))
    layout = jax.tree_util.tree_map(lambda x: x[0], meas)
    return tables, np.asarray(flat_samples(meas)), layout


def test_log_relative_round_trip(rng):
    x = rng.uniform(0, 5, (50, 3))
    ref = rng.uniform(0.01, 2, (50, 3))
    cos_v = rng.uniform(0.2, 1, (50, 1))
    m = log_relative(x, ref, cos_v, 1e-3)
    np.testing.assert_allclose(inverse_log_relative(m, ref, cos_v, 1e-3), x, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(log_relative(ref, ref, cos_v, 1e-3), 0, atol=1e-12)


@pytest.mark.parametrize("channels", ["joint", "shared"])
def test_pca_reproduces_a_material_of_its_basis(database, channels):
    """With every component kept and λ → 0, a training material is rebuilt from its own samples."""
    tables, flat, layout = database
    prior = fit_pca_prior(tables, flat, layout, n_components=None, channels=channels, dtype=F64)
    assert prior.n_components == (len(tables) - 1 if channels == "joint" else 3 * len(tables) - 1)
    for k in (1, 4):
        rec = np.asarray(reconstruct_pca(prior, 1e-10, jnp.asarray(flat[k : k + 1])))[0]
        scale = np.abs(tables[k]).max()
        np.testing.assert_allclose(rec, tables[k], atol=1e-6 * scale)


def test_pca_ridge_is_the_augmented_least_squares(database, rng):
    """Oracle for the ridge projection: ``lstsq`` of ``[Q_s; √λ I] c = [z; 0]``."""
    tables, flat, layout = database
    prior = fit_pca_prior(tables[:6], flat[:6], layout, n_components=4, channels="joint", dtype=F64)
    lam = 0.3
    r = np.asarray(prior.ridge_operator(lam))
    z = rng.normal(size=prior.comps_s.shape[0])
    q = np.asarray(prior.comps_s)
    aug = np.vstack([q, np.sqrt(lam) * np.eye(q.shape[1])])
    want = np.linalg.lstsq(aug, np.concatenate([z, np.zeros(q.shape[1])]), rcond=None)[0]
    np.testing.assert_allclose(r @ z, want, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("basis_at", ["models", "tables"])
def test_pca_held_out_material_is_finite_and_non_negative(database, basis_at):
    tables, flat, layout = database
    prior = fit_pca_prior(
        tables[:-1], flat[:-1], layout, n_components=5, basis_at=basis_at, dtype=F64
    )
    rec = np.asarray(reconstruct_pca(prior, 1.0, jnp.asarray(flat[-1:])))
    assert rec.shape == (1, 81, 81, 3)
    assert np.all(np.isfinite(rec)) and np.all(rec >= 0)
    # the prior is informative: the held-out material is closer than a constant (mean) table
    fill = np.broadcast_to(flat[-1].mean(0), tables[-1:].shape)
    err = lambda t: float(np.mean(np.abs(np.log1p(t) - np.log1p(tables[-1:]))))  # noqa: E731
    assert err(rec) < 0.5 * err(fill)


def _canonical(alpha_x, alpha_y, rotation):
    """GGX/Ward are unchanged by (αx, αy, φ) → (αy, αx, φ + π/2) and φ → φ + π."""
    if alpha_x > alpha_y:
        alpha_x, alpha_y, rotation = alpha_y, alpha_x, rotation + np.pi / 2
    return alpha_x, alpha_y, float(np.mod(rotation, np.pi))


def test_analytic_fit_recovers_known_ggx():
    """Noise-free aniso204 samples of two anisotropic GGX materials: parameters and tables recovered."""
    truth = [
        dict(diffuse=[0.10, 0.20, 0.30], specular_f0=0.3, alpha_x=0.08, alpha_y=0.25, rotation=0.5),
        dict(
            diffuse=[0.40, 0.10, 0.05], specular_f0=0.05, alpha_x=0.35, alpha_y=0.12, rotation=2.0
        ),
    ]
    mats = [GGX(**t) for t in truth]
    cfg = aj.Config(budget="aniso204")
    p = aj.Params.default(cfg, dtype=F64)
    meas = aj.stack_measurements([aj.sample(m, cfg, p, as_measurements=True) for m in mats])
    fit = fit_analytic(meas, model="ggx", eps_rel=1e-3)
    got = {k: np.asarray(v) for k, v in fit.params().items()}
    tables = np.asarray(fit.tables())
    assert np.all(np.isfinite(tables)) and np.all(tables >= 0)
    for k, t in enumerate(truth):
        assert float(fit.loss[k]) < 1e-10
        np.testing.assert_allclose(got["kd"][k], t["diffuse"], rtol=1e-4)
        np.testing.assert_allclose(got["ks"][k] * 1.0, 1.0, rtol=1e-3)  # the truth has ks = 1
        np.testing.assert_allclose(got["f0"][k], t["specular_f0"], rtol=1e-3)
        want = _canonical(t["alpha_x"], t["alpha_y"], t["rotation"])
        have = _canonical(
            float(got["alpha_x"][k]), float(got["alpha_y"][k]), float(got["rotation"][k])
        )
        np.testing.assert_allclose(have, want, rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(
            tables[k], dense_table(mats[k], np.float64), rtol=1e-4, atol=1e-8
        )
    # float32 samples with x64 on (the suite's float32 points): fitted in float64, float32 tables back
    meas32 = jax.tree_util.tree_map(lambda a: a.astype(jnp.float32) if a.dtype == F64 else a, meas)
    rec32 = reconstruct_analytic(meas32, model="ggx", eps_rel=1e-3)
    assert rec32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(rec32), tables, rtol=1e-3, atol=1e-6)
