"""RBF interpolation against scipy's RBFInterpolator (the oracle), in float64."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.interpolate import RBFInterpolator

from abrdf_jax import KERNELS, fit_rbf, rbf_interpolate
from abrdf_jax._kernels import kernel_fn, min_degree

SCIPY_NAME = {"inverse_quadratic": "inverse_quadratic"}


def points(rng, n, d=4):
    return rng.uniform(-1.2, 1.2, (n, d))


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("reg", [0.0, 1e-3])
def test_matches_scipy(kernel, reg, rng):
    x = points(rng, 60)
    y = np.stack([np.sin(x @ [1, 0.5, -0.3, 0.2]), np.cos(x[:, 0] * x[:, 1])], -1)
    xq = points(rng, 40)
    widths = np.array([0.7, 1.3, 0.9, 2.0])
    degree = max(min_degree(kernel), 0) if kernel in ("gaussian",) else None
    ours = rbf_interpolate(
        jnp.asarray(x), jnp.asarray(y), jnp.asarray(xq), jnp.asarray(widths), kernel, reg, degree
    )
    sp_degree = min_degree(kernel) if degree is None else degree
    ref = RBFInterpolator(
        x / widths,
        y,
        kernel=SCIPY_NAME.get(kernel, kernel),
        epsilon=1.0,
        smoothing=reg,
        degree=sp_degree,
    )(xq / widths)
    np.testing.assert_allclose(ours, ref, rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("kernel", KERNELS)
def test_interpolates_at_centres(kernel, rng):
    x = points(rng, 30)
    y = rng.normal(size=(30, 3))
    interp = fit_rbf(jnp.asarray(x), jnp.asarray(y), jnp.ones(4) * 0.8, kernel, 0.0)
    np.testing.assert_allclose(interp(jnp.asarray(x)), y, atol=1e-7)


def test_constant_tail_reproduces_constants(rng):
    x = points(rng, 30)
    y = np.full((30, 1), 3.5)
    out = rbf_interpolate(
        jnp.asarray(x),
        jnp.asarray(y),
        jnp.asarray(points(rng, 10) * 3),
        jnp.ones(4),
        "gaussian",
        1e-3,
        0,
    )
    np.testing.assert_allclose(out, 3.5, rtol=1e-10)


@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_gradient_finite_at_zero_distance(kernel):
    fn = kernel_fn(kernel)
    g = jax.grad(lambda r2: fn(r2))(jnp.asarray(0.0))
    assert np.isfinite(g)


@pytest.mark.parametrize("kernel", ["gaussian", "thin_plate_spline", "multiquadric"])
def test_gradients_wrt_widths_and_reg(kernel, rng):
    x = jnp.asarray(points(rng, 25))
    y = jnp.asarray(np.sin(np.asarray(x).sum(-1, keepdims=True)))
    # queries include the centres themselves: coincident points, zero distances
    xq = jnp.concatenate([x[:5], jnp.asarray(points(rng, 5))])

    def f(widths, reg):
        return jnp.sum(rbf_interpolate(x, y, xq, widths, kernel, reg) ** 2)

    w0, r0 = jnp.array([0.8, 1.1, 0.9, 1.3]), jnp.asarray(1e-2)
    gw, gr = jax.grad(f, argnums=(0, 1))(w0, r0)
    assert np.all(np.isfinite(gw)) and np.isfinite(gr)
    check_grads(f, (w0, r0), order=1, modes=("rev",), atol=1e-4, rtol=1e-4)


def test_vmap_over_values_equals_loop(rng):
    x = jnp.asarray(points(rng, 20))
    ys = jnp.asarray(rng.normal(size=(4, 20, 3)))
    xq = jnp.asarray(points(rng, 7))
    w = jnp.ones(4) * 0.9
    batched = jax.vmap(lambda y: rbf_interpolate(x, y, xq, w, "gaussian", 1e-4))(ys)
    loop = jnp.stack([rbf_interpolate(x, y, xq, w, "gaussian", 1e-4) for y in ys])
    np.testing.assert_allclose(batched, loop, rtol=1e-10, atol=1e-12)


def test_bad_degree_raises():
    with pytest.raises(ValueError, match="degree >= 1"):
        fit_rbf(jnp.zeros((3, 4)), jnp.zeros((3, 1)), jnp.ones(4), "thin_plate_spline", 0.0, 0)
    with pytest.raises(ValueError, match="kernel must be one of"):
        fit_rbf(jnp.zeros((3, 4)), jnp.zeros((3, 1)), jnp.ones(4), "sinc", 0.0)
