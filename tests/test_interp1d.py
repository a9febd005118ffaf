import jax
import jax.numpy as jnp
import numpy as np
import pytest

from abrdf_jax._interp1d import periodic_interp


def _slice(n, nmax, f, rng=None, jitter=False):
    t = np.arange(n) * 2 * np.pi / n
    if jitter:
        t = np.sort(t + rng.uniform(0, 0.3, n) * 2 * np.pi / n)
    tp = np.zeros(nmax)
    tp[:n] = t
    y = np.zeros((nmax, 1))
    y[:n, 0] = f(t)
    return jnp.asarray(tp), jnp.asarray(y)


@pytest.mark.parametrize("method", ["linear", "cubic"])
def test_exact_at_knots_and_periodic(method, rng):
    t, y = _slice(7, 12, np.sin, rng, jitter=True)
    out = periodic_interp(t, y, 7, t[:7], method)
    np.testing.assert_allclose(out, y[:7], atol=1e-12)
    out2 = periodic_interp(t, y, 7, t[:7] + 2 * np.pi, method)
    np.testing.assert_allclose(out2, y[:7], atol=1e-12)


def test_linear_between_knots_including_wrap():
    t, y = _slice(4, 6, lambda t: np.array([0.0, 1.0, 3.0, 7.0]))
    q = jnp.array([np.pi / 4, 3 * np.pi / 4, 7 * np.pi / 4, -np.pi / 4])
    # halfway between knots; the last interval wraps from 7 back to 0
    np.testing.assert_allclose(periodic_interp(t, y, 4, q)[:, 0], [0.5, 2.0, 3.5, 3.5])


def test_cubic_converges_on_smooth_data():
    q = jnp.linspace(0, 2 * np.pi, 101)
    errs = []
    for n in (12, 24, 48):
        t, y = _slice(n, n, lambda t: np.cos(2 * t))
        errs.append(
            float(jnp.max(jnp.abs(periodic_interp(t, y, n, q, "cubic")[:, 0] - jnp.cos(2 * q))))
        )
    assert errs[1] < errs[0] / 4 and errs[2] < errs[1] / 4  # better than first order


def test_traced_count_and_gradient_finite():
    t, y = _slice(5, 8, np.cos)
    f = jax.jit(lambda n, q: periodic_interp(t, y, n, q))
    np.testing.assert_allclose(f(5, t[:5]), y[:5], atol=1e-12)
    g = jax.grad(lambda q: periodic_interp(t, y, 5, q[None])[0, 0])(jnp.asarray(0.3))
    assert np.isfinite(g)


def test_duplicate_knots_do_not_give_nan():
    t = jnp.array([0.0, 1.0, 1.0, 2.0])
    y = jnp.array([[0.0], [1.0], [2.0], [3.0]])
    out = periodic_interp(t, y, 4, jnp.array([1.0, 0.5, 1.5]))
    assert np.all(np.isfinite(out))
    g = jax.grad(lambda q: periodic_interp(t, y, 4, q[None])[0, 0])(jnp.asarray(1.0))
    assert np.isfinite(g)
