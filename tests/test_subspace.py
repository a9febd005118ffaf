"""The toroidal subspace rules against hand-made slices whose answer is known."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from abrdf_jax import subspace
from abrdf_jax._slices import slice_angles

N = 24
ALPHA = (
    2 * 2 * np.pi / N
)  # 30 deg: the crossings fall on knots, so linear interpolation is exact there


def f(s):
    return 1.0 + 0.3 * np.cos(s) + 0.1 * np.sin(2 * s)


def g(d):
    return 2.0 + np.cos(d) + 0.5 * np.cos(3 * d)


def make_slices(fn):
    """Sample B(φi, φv) = fn(s, d) on both slices at t_k = 2πk/N."""
    t = np.arange(N) * 2 * np.pi / N
    ai, av = slice_angles("axial", jnp.asarray(t), ALPHA)
    di, dv = slice_angles("diagonal", jnp.asarray(t), ALPHA)
    ya = fn(np.asarray(ai + av), np.asarray(ai - av))[:, None]
    yd = fn(np.asarray(di + dv), np.asarray(di - dv))[:, None]
    return jnp.asarray(t), jnp.asarray(ya), jnp.asarray(yd)


def knot_queries():
    """Points whose slice preimages are knots: φi = t_k − u_j + π, φv = t_k + u_j − π − α."""
    t = np.arange(N) * 2 * np.pi / N
    tk, uj = np.meshgrid(t, t, indexing="ij")
    return jnp.asarray((tk - uj + np.pi).ravel()), jnp.asarray((tk + uj - np.pi - ALPHA).ravel())


def run(rule, fn, **kw):
    t, ya, yd = make_slices(fn)
    pi_, pv = knot_queries()
    out = subspace(t, ya, N, t, yd, N, pi_, pv, jnp.asarray(ALPHA), rule=rule, **kw)
    truth = fn(np.asarray(pi_ + pv), np.asarray(pi_ - pv))
    return np.asarray(out[:, 0]), truth


def test_slice_geometry_hand_cases():
    # axial: φv = φi − α ; diagonal: φi = 2π − φv + α (mod 2π)
    a = np.deg2rad(15.0)
    pi_, pv = slice_angles("axial", jnp.deg2rad(jnp.array([0.0, 100.0])), a)
    np.testing.assert_allclose(np.rad2deg(pi_), [0.0, 100.0])
    np.testing.assert_allclose(np.rad2deg(pv), [345.0, 85.0])
    pi_, pv = slice_angles("diagonal", jnp.deg2rad(jnp.array([0.0, 100.0])), a)
    np.testing.assert_allclose(np.rad2deg(pi_), [15.0, 275.0])
    np.testing.assert_allclose(np.rad2deg(pv), [0.0, 100.0])


def test_crossing_rule_reproduces_additive_separable_subspace():
    out, truth = run("crossing", lambda s, d: f(s) + g(d))
    np.testing.assert_allclose(out, truth, atol=1e-12)


def test_log_rule_reproduces_multiplicative_subspace():
    # exact up to the guard ε (relative to the mean sample); a tiny ε leaves float64 rounding
    out, truth = run("log", lambda s, d: f(s) * g(d), log_eps=1e-9)
    np.testing.assert_allclose(out, truth, rtol=1e-7)


def test_diagonal_rule_reproduces_isotropic_subspace():
    out, truth = run("diagonal", lambda s, d: g(d))
    np.testing.assert_allclose(out, truth, atol=1e-12)


def test_filip2012_equals_eq5_for_constant_axial_slice():
    # isotropic data: the axial slice is constant, inside the diagonal slice's range
    out_a, _ = run("filip2012", lambda s, d: g(d))
    out_d, _ = run("diagonal", lambda s, d: g(d))
    np.testing.assert_allclose(out_a, out_d, atol=1e-12)


def test_filip2012_stays_in_slice_range_and_average_is_half_sum():
    fn = lambda s, d: f(s) + g(d)  # noqa: E731
    t, ya, yd = make_slices(fn)
    pi_, pv = jnp.asarray(np.random.default_rng(1).uniform(0, 2 * np.pi, (2, 500)))
    out = subspace(t, ya, N, t, yd, N, pi_, pv, jnp.asarray(ALPHA), rule="filip2012")
    lo = min(ya.min(), yd.min())
    hi = max(ya.max(), yd.max())
    assert float(out.min()) >= lo - 1e-12 and float(out.max()) <= hi + 1e-12
    avg = subspace(t, ya, N, t, yd, N, pi_, pv, jnp.asarray(ALPHA), rule="average")
    a = subspace(t, ya, N, t, yd, N, pi_, pv, jnp.asarray(ALPHA), rule="crossing")
    assert avg.shape == a.shape == (500, 1)


def test_constant_material_constant_subspace_every_rule():
    for rule in ("filip2012", "average", "crossing", "log", "diagonal"):
        out, _ = run(rule, lambda s, d: 0 * s + 0.7)
        np.testing.assert_allclose(out, 0.7, rtol=1e-9, err_msg=rule)


@pytest.mark.parametrize("rule", ["filip2012", "average", "crossing", "log", "diagonal"])
def test_gradients_finite_in_alpha_and_values(rule):
    t, ya, yd = make_slices(lambda s, d: f(s) + g(d))
    pi_, pv = knot_queries()

    def loss(alpha, ya, yd):
        return jnp.sum(subspace(t, ya, N, t, yd, N, pi_, pv, alpha, rule=rule) ** 2)

    grads = jax.grad(loss, argnums=(0, 1, 2))(jnp.asarray(ALPHA + 0.01), ya, yd)
    for gr in grads:
        assert np.all(np.isfinite(gr))


def test_unknown_rule_raises():
    t, ya, yd = make_slices(lambda s, d: f(s) + g(d))
    with pytest.raises(ValueError, match="unknown subspace rule"):
        subspace(t, ya, N, t, yd, N, t, t, jnp.asarray(ALPHA), rule="nope")
