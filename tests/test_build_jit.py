"""``build_jit``: build-once programs compiled cheaply, with ``equinox.filter_jit``'s semantics
(the operator built through it equals the pipeline: tests/test_operator.py)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from abrdf_jax._build_jit import build_jit

TRACES = []


def _kernel_solve(x, y, width, *, power=2, name="gauss"):
    TRACES.append((width, power, name))
    d = jnp.abs(x[:, None] - x[None, :]) ** power
    k = jnp.exp(-d / width**power) + 1e-3 * jnp.eye(x.shape[0], dtype=x.dtype)
    return jnp.linalg.solve(k, y)


def test_same_numbers_as_the_optimised_program_and_one_trace_per_static_value():
    x = np.linspace(0.0, 1.0, 40)
    y = np.sin(7 * x)
    fast = build_jit(_kernel_solve)
    ref = eqx.filter_jit(_kernel_solve)
    TRACES.clear()
    a = fast(x, jnp.asarray(y), 0.3, power=2)
    b = ref(x, jnp.asarray(y), 0.3, power=2)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-4)
    assert np.all(np.isfinite(np.asarray(a)))
    n = len(TRACES)
    fast(x + 0.5, jnp.asarray(y), 0.3, power=2)  # new array values: no new trace
    assert len(TRACES) == n
    fast(x, jnp.asarray(y), 0.5, power=2)  # a static value changes: traced again
    fast(x, jnp.asarray(y), 0.5, power=1, name="exp")
    assert [t[1:] for t in TRACES[n:]] == [(2, "gauss"), (1, "exp")]


def test_differentiable_through_the_build():
    x = np.linspace(0.0, 1.0, 12)
    y = np.cos(3 * x)

    def loss(width):
        return jnp.sum(build_jit(_kernel_solve)(x, y, jnp.asarray(1.0)) * width) + jnp.sum(
            build_jit(_kernel_solve)(x * width, y, 0.4)
        )

    g = jax.grad(loss)(jnp.asarray(1.2))
    eps = 1e-3
    fd = (loss(jnp.asarray(1.2 + eps)) - loss(jnp.asarray(1.2 - eps))) / (2 * eps)
    np.testing.assert_allclose(float(g), float(fd), rtol=2e-2)


def test_a_jaxlib_without_an_option_compiles_with_the_others(monkeypatch):
    """An XLA option this jaxlib does not know (e.g. the fusion emitters' switch of an older
    one) is not fatal: the build compiles with the remaining options, the same numbers."""
    import abrdf_jax._build_jit as bj

    monkeypatch.setattr(bj, "FAST_COMPILE", {**bj.SAFE_COMPILE, "xla_no_such_option_zz": False})
    monkeypatch.setattr(bj, "_FAST_OK", [None])
    x = np.linspace(0.0, 1.0, 20)
    y = np.sin(5 * x)
    a = bj.build_jit(_kernel_solve)(x, jnp.asarray(y), 0.3)
    assert bj._FAST_OK == [False]
    b = eqx.filter_jit(_kernel_solve)(x, jnp.asarray(y), 0.3)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-4)


def test_other_compile_errors_are_not_swallowed(monkeypatch):
    import abrdf_jax._build_jit as bj

    monkeypatch.setattr(bj, "_FAST_OK", [None])

    def bad(x):
        raise ValueError("a bug in the traced function")

    with pytest.raises(ValueError, match="a bug"):
        bj.build_jit(bad)(np.ones(3))
    assert bj._FAST_OK == [None]
