"""Numerical edges: the RBF guard, data edges without NaN/inf, finite gradients at the limits.

The measured picture (condition numbers, error against width, λ, noise, anisotropy) comes from
``python -m benchmarks.stability``; these tests assert the guarantees that docs/stability.md
("Numerical edges") states. Few distinct shapes and configurations, to keep the compiles few.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax.cli import main
from abrdf_jax._errors import InputError
from abrdf_jax._arrays import check_finite
from abrdf_jax._pipeline import solve_info
from abrdf_jax._rbf import GUARD_FACTOR, fit_rbf_info
from abrdf_jax import group_slices
from abrdf_jax._subspace import RULES, subspace

N, DUP = 24, 8  # every RBF system below has N + DUP = 32 centres (one compile per kernel)


def _duplicated(rng):
    x = rng.uniform(-1.0, 1.0, (N, 4))
    return jnp.asarray(np.concatenate([x, x[:DUP]]))  # the first DUP centres twice: K is singular


def _random(rng):
    return jnp.asarray(rng.uniform(-1.0, 1.0, (N + DUP, 4)))


# ---------------------------------------------------------------------------------------------
# the guard


@pytest.mark.parametrize("kernel", ["gaussian", "thin_plate_spline"])  # Cholesky path, LU path
def test_guard_engages_on_duplicated_samples(kernel, rng):
    x = _duplicated(rng)
    y = rng.normal(size=(N + DUP, 2))
    y[-DUP:] = y[:DUP] + 0.5  # the duplicates disagree: no exact interpolant exists
    y = jnp.asarray(y)
    widths = jnp.full(4, 0.8)
    _, bare = fit_rbf_info(x, y, widths, kernel, 0.0, guard=False)
    assert not bool(bare.ok)  # detected as singular to working precision
    interp, info = fit_rbf_info(x, y, widths, kernel, 0.0)
    assert int(info.retries) == 1 and bool(info.ok)
    norm1 = float(jnp.max(jnp.sum(jnp.abs(aj._rbf.gram(x, widths, kernel)), axis=0)))
    np.testing.assert_allclose(
        float(info.reg), GUARD_FACTOR * np.finfo(np.float64).eps * norm1, rtol=1e-10
    )
    assert float(info.cond) * np.finfo(np.float64).eps < 1
    out = interp(x)
    assert np.all(np.isfinite(out))
    # With a tiny nugget the fit at a duplicated centre is the mean of its two values (least
    # squares), elsewhere it still interpolates. The coefficients grow like |Δy| / λ₁ with
    # λ₁ = GUARD_FACTOR·ε·‖K‖₁, so rounding leaves an error of about |Δy| / GUARD_FACTOR.
    tol = 0.5 / GUARD_FACTOR
    np.testing.assert_allclose(out[:DUP], (y[:DUP] + y[-DUP:]) / 2, atol=tol)
    np.testing.assert_allclose(out[DUP:-DUP], y[DUP:-DUP], atol=tol)


@pytest.mark.parametrize("kernel", ["gaussian", "thin_plate_spline"])
def test_guard_leaves_well_conditioned_systems_alone(kernel, rng):
    x, y = _random(rng), jnp.asarray(rng.normal(size=(N + DUP, 2)))
    a, info = fit_rbf_info(x, y, jnp.full(4, 0.7), kernel, 1e-6)
    b, bare = fit_rbf_info(x, y, jnp.full(4, 0.7), kernel, 1e-6, guard=False)
    assert int(info.retries) == 0 and bool(info.ok) and float(info.reg) == 1e-6
    np.testing.assert_array_equal(a.coeffs, b.coeffs)
    np.testing.assert_array_equal(a.poly_coeffs, b.poly_coeffs)
    # The Hager estimate is a lower bound of the exact 1-norm condition number, and close to it.
    k = np.asarray(aj._rbf.gram(x, jnp.full(4, 0.7), kernel)) + 1e-6 * np.eye(N + DUP)
    if kernel == "thin_plate_spline":
        from abrdf_jax._rbf_system import blocks, centre_stats, system

        kk, p, _ = blocks(x, jnp.full(4, 0.7), kernel, 1, *centre_stats(x))
        k = np.asarray(system(kk, p, jnp.asarray(1e-6)))
    exact = np.linalg.cond(k, 1)
    assert exact / 3 <= float(bare.cond) <= exact * (1 + 1e-8)


# ---------------------------------------------------------------------------------------------
# data edges through the pipeline


def _edge_batch(cfg, dtype, model="lambert-clay"):
    """All-zero, constant, a mirror-like peak 1e4 above the diffuse level, 5% negative samples."""
    params = aj.Params.default(cfg, dtype=dtype)
    base = aj.sample(aj.materials.get_material(model), cfg, params, as_measurements=True)
    y = np.asarray(base.y)
    valid = (np.arange(y.shape[1])[None, :] < np.asarray(base.count)[:, None])[..., None]
    peak = y.copy()
    peak[1, 0] = 1e4 * y.max()  # one sample of one slice dominates
    neg = np.where(
        valid & (np.random.default_rng(1).random(y.shape[:2])[..., None] < 0.05),
        -0.01 * y.mean(),
        y,
    )
    ys = [np.zeros_like(y), np.where(valid, 0.3, 0.0) * np.ones_like(y), peak, neg]
    items = [
        aj.Measurements(base.t, jnp.asarray(v, dtype), base.count, base.pairs, base.has_axial)
        for v in ys
    ]
    return aj.stack_measurements(items), params


@pytest.mark.parametrize("preset", ["paper", "recommended"])
def test_data_edges_never_give_nan_or_inf(preset):
    dtype = jnp.float32
    cfg = aj.Config() if preset == "paper" else aj.Config.recommended()
    batch, params = _edge_batch(cfg, dtype)
    # The presets' systems are well conditioned in float32, with a margin (the CLI skips the
    # guard's diagnostics for them).
    info = solve_info(batch, cfg, params)
    assert int(info.retries) == 0 and bool(info.ok)
    assert float(info.cond) * np.finfo(np.float32).eps < 0.5
    out = np.asarray(aj.reconstruct_batch(batch, cfg, params))
    assert out.dtype == dtype
    assert np.all(np.isfinite(out)) and out.min() >= 0
    np.testing.assert_allclose(out[0], 0.0, atol=1e-6)  # all-zero in, zero out
    if preset == "recommended":  # a polynomial tail reproduces constants
        np.testing.assert_allclose(out[1], 0.3, rtol=1e-4)
    peak_in = float(np.max(np.asarray(batch.y[2])))
    assert out[2].max() <= 10 * peak_in  # rings, but boundedly
    if preset == "paper":
        # The paper's Gaussian made very wide without regularisation: singular, guarded, finite
        # (same shapes and configuration: no new compile).
        wide = aj.Params(params.alpha, jnp.full(4, 6.0, dtype), jnp.asarray(0.0, dtype))
        info = solve_info(batch, cfg, wide)
        assert int(info.retries) == 1 and float(info.reg) > 0
        out = np.asarray(aj.reconstruct_batch(batch, cfg, wide))
        assert np.all(np.isfinite(out)) and out.min() >= 0


def test_missing_slice_falls_back_to_the_other(rng):
    """A slice with no samples never feeds padding into a rule: eq. (5) (or the axial slice) instead."""
    nmax = 8
    t = jnp.asarray(np.sort(rng.uniform(0, 2 * np.pi, nmax)))
    ya, yd = (
        jnp.asarray(rng.uniform(0.1, 1, (nmax, 3))),
        jnp.asarray(rng.uniform(0.1, 1, (nmax, 3))),
    )
    other = jnp.asarray(rng.uniform(5, 9, (nmax, 3)))  # values a missing slice must not influence
    pi_, pv = jnp.asarray(rng.uniform(0, 2 * np.pi, 16)), jnp.asarray(rng.uniform(0, 2 * np.pi, 16))

    @jax.jit
    def every_rule(alpha, ya, na, yd, nd):
        return jnp.stack([subspace(t, ya, na, t, yd, nd, pi_, pv, alpha, rule=r) for r in RULES])

    alpha = jnp.asarray(np.deg2rad(15.0))
    diag = every_rule(alpha, ya, 6, yd, 7)[list(RULES).index("diagonal")]
    no_axial = every_rule(alpha, other, 0, yd, 7)
    np.testing.assert_allclose(no_axial, jnp.broadcast_to(diag, no_axial.shape), rtol=1e-12)
    no_diag = every_rule(alpha, ya, 6, other, 0)
    keep = np.array([k for k, r in enumerate(RULES) if r != "diagonal"])
    assert (
        np.all(np.isfinite(no_diag)) and float(jnp.min(no_diag[keep[0]])) >= 0.1
    )  # the axial slice's values
    np.testing.assert_allclose(
        no_diag[keep], jnp.broadcast_to(no_diag[keep[0]], no_diag[keep].shape), rtol=1e-12
    )
    # filip2012 reads the slices' extremes (±inf over an empty slice): gradients stay finite, and
    # the missing slice's values get none.
    ga, gy = jax.jit(
        jax.grad(
            lambda a, y: jnp.sum(subspace(t, y, 0, t, yd, 7, pi_, pv, a, rule="filip2012") ** 2),
            argnums=(0, 1),
        )
    )(alpha, ya)
    assert np.isfinite(ga) and np.all(np.isfinite(gy)) and not np.any(gy)


def test_an_elevation_pair_without_samples_is_left_out():
    cfg = aj.Config(budget="aniso204")
    meas = aj.sample(aj.materials.get_material("ward-brushed-steel"), cfg, as_measurements=True)
    s = meas.to_samples().to_numpy()
    keep = ~((np.asarray(s.theta_i) == 75) & (np.asarray(s.theta_v) == 75))
    part = aj.Samples(
        *(np.asarray(a)[keep] for a in (s.theta_i, s.phi_i, s.theta_v, s.phi_v, s.rgb))
    )
    m, report = group_slices(part, 15.0)
    assert m.pairs == ((30.0, 30.0), (30.0, 75.0), (75.0, 30.0)) and report["dropped_pairs"] == [
        (75.0, 75.0)
    ]
    assert all(c > 0 for c in report["counts"])
    full, report = group_slices(s, 15.0)
    assert len(full.pairs) == 4 and report["dropped_pairs"] == []


# ---------------------------------------------------------------------------------------------
# no NaN reaches a table


def test_check_finite_refuses_nan_and_inf():
    table = np.zeros((81, 81, 3), np.float32)
    check_finite(table, "m.csv")
    table[3, 4, 1] = np.inf
    table[5, 0, 0] = np.nan
    with pytest.raises(
        InputError,
        match=r"m.csv: the reconstruction holds 2 NaN or infinite value\(s\) \(first at index \(3, 4, 1\)\)",
    ):
        check_finite(table, "m.csv")


def test_cli_overflow_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """Finite samples near float32's limit overflow the paper method's linear RBF: exit 2, no file.

    (The anisotropic paper model runs the general pipeline; the compiled operator of the
    isotropic one stays finite even at float32's limit: tests/test_engine.py has the CLI's paths.)
    """
    monkeypatch.chdir(tmp_path)
    cfg = aj.Config(budget="aniso204")
    meas = aj.sample(aj.materials.get_material("ggx-plastic"), cfg, as_measurements=True)
    s = meas.to_samples().to_numpy()
    rows = np.column_stack([s.theta_i, s.phi_i, s.theta_v, s.phi_v, np.asarray(s.rgb) * 1e37])
    (tmp_path / "big.csv").write_text(
        "theta_i,phi_i,theta_v,phi_v,r,g,b\n"
        + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows)
    )
    status = main(["reconstruct", "big.csv", "-o", "rec.npz", "--model", "paper-aniso"])
    err = capsys.readouterr().err
    assert status == 2, err
    errors = [line for line in err.splitlines() if line.startswith("abrdf-jax: error:")]
    assert len(errors) == 1, err  # progress lines of a long stage may come before it
    assert errors[0].startswith("abrdf-jax: error: big.csv: the reconstruction holds")
    assert "nothing was written" in errors[0]
    assert not (tmp_path / "rec.npz").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "big.csv"
    ]  # no temporary file left either


# ---------------------------------------------------------------------------------------------
# gradients at the edges the fitting uses


def test_gradients_at_coincident_centres(rng):
    """Coincident centres with equal values (the guard engages): finite gradients in widths and
    values; on distinct centres down to widths far below their spacing (K → I) the gradient
    matches finite differences, and stays finite at 1e-3."""
    xd, xr = _duplicated(rng), _random(rng)
    y0 = rng.normal(size=(N + DUP, 1))
    y0[-DUP:] = y0[:DUP]
    y0 = jnp.asarray(y0)
    xq = jnp.asarray(rng.uniform(-1.0, 1.0, (10, 4)))

    def loss(widths, y, x):
        interp, _ = fit_rbf_info(x, y, widths, "gaussian", 0.0)
        return jnp.sum(interp(xq) ** 2)

    f = jax.jit(loss)
    g = jax.jit(jax.grad(loss, argnums=(0, 1)))
    gw, gy = g(jnp.full(4, 0.8), y0, xd)
    assert np.all(np.isfinite(gw)) and np.all(np.isfinite(gy))
    v = jnp.asarray([1.0, -0.5, 0.25, 0.7])
    for w0, h in ((0.3, 1e-6), (0.1, 1e-7)):
        w = jnp.full(4, w0)
        fd = (f(w + h * v, y0, xr) - f(w - h * v, y0, xr)) / (2 * h)
        np.testing.assert_allclose(jnp.dot(g(w, y0, xr)[0], v), fd, rtol=1e-5, atol=1e-9)
    gw, gy = g(jnp.full(4, 1e-3), y0, xr)
    assert np.all(np.isfinite(gw)) and np.all(np.isfinite(gy))


def test_gradients_finite_at_clamped_alpha():
    """α at 0 (light and camera on the same azimuth line) and at 90°: the pipeline's gradients
    in α and the widths stay finite, and match finite differences at α = 0."""
    cfg = aj.Config()
    model = aj.materials.get_material("ward-brushed-steel")
    wi = aj.to_vector(np.full(6, 0.5), np.linspace(0, 5, 6))
    wv = aj.to_vector(np.full(6, 0.7), np.linspace(1, 6, 6))
    truth = model(wi, wv)
    widths = aj.Params.default(cfg).widths

    def loss(alpha, widths):
        p = aj.Params(alpha, widths, jnp.asarray(1e-2))
        meas = aj.sample(model, cfg, p, as_measurements=True)
        return jnp.mean((aj.reconstruct(meas, cfg, p, targets=(wi, wv)) - truth) ** 2)

    vg = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
    for a in (0.0, np.pi / 2):
        _, (ga, gw) = vg(jnp.asarray(a), widths)
        assert np.isfinite(ga) and np.all(np.isfinite(gw)), a
    # Central differences on [0, 2ε] (α < 0 would wrap the slices), against the gradient at ε.
    eps = 1e-5
    fd = (vg(jnp.asarray(2 * eps), widths)[0] - vg(jnp.asarray(0.0), widths)[0]) / (2 * eps)
    np.testing.assert_allclose(vg(jnp.asarray(eps), widths)[1][0], fd, rtol=1e-3, atol=1e-9)
