"""The compiled operator's low-rank factors (``abrdf_jax._low_rank``): exact to rounding, used
only where they save work, and the operator's output unchanged by them."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax._low_rank import MAX_COLUMNS, MAX_WORK, low_rank_factors
from abrdf_jax._operator import TILE
from abrdf_jax.materials import get_material


def test_factors_reproduce_a_low_rank_matrix():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(400, 30)) @ rng.normal(size=(30, 90))  # rank 30 of 90 columns
    u, w = low_rank_factors(m)
    assert u.shape == (400, 30) and w.shape == (30, 90)
    np.testing.assert_allclose(u @ w, m, rtol=0, atol=1e-12 * np.abs(m).max())


def test_no_factors_where_they_would_not_pay_or_cannot_be_trusted():
    rng = np.random.default_rng(1)
    full = rng.normal(size=(400, 90))
    assert low_rank_factors(full) is None  # full rank: the dense product
    r = int(MAX_WORK * 400 * 90 / (400 + 90)) + 1  # just above the work limit
    near = rng.normal(size=(400, r)) @ rng.normal(size=(r, 90))
    assert low_rank_factors(near) is None
    wide = rng.normal(size=(600, 10)) @ rng.normal(size=(10, MAX_COLUMNS + 1))
    assert low_rank_factors(wide) is None  # its SVD would cost more than the build
    low = rng.normal(size=(400, 10)) @ rng.normal(size=(10, 90))
    assert low_rank_factors(low.astype(np.float32)) is None  # float32: rounding hides the rank
    assert low_rank_factors(np.zeros((400, 90))) is None
    bad = low.copy()
    bad[0, 0] = np.nan
    assert low_rank_factors(bad) is None
    seen = []
    jax.jit(lambda a: seen.append(low_rank_factors(a)) or a)(jnp.ones((4, 3)))
    assert seen == [None]  # a traced matrix


@pytest.mark.parametrize("budget", ["iso102", "aniso204"])
def test_operator_through_its_factors_equals_the_dense_product(budget):
    """The operator of the command line's settings built in float64 (``build_dtype="host"``)
    has factors (rank 84 of 102, 156 of 204 columns), and its tables equal those of the same
    operator without them to float32 rounding, for a batch above the tile too."""
    cfg = aj.preset("operator", budget)
    params = aj.Params.default(cfg)
    meas = aj.sample(get_material("ward-brushed-steel"), cfg, params, as_measurements=True)
    op = aj.compile_operator(cfg, params, meas, build_dtype="host")
    assert op.factors is not None
    u, w = op.factors
    assert u.shape[1] == w.shape[0] < op.n_inputs and u.dtype == op.dtype
    dense = eqx.tree_at(lambda o: o.factors, op, replace=None)
    rng = np.random.default_rng(2)
    y = np.asarray(meas.y)[None] * rng.uniform(0.5, 2.0, (TILE + 3, 1, 1, 3)).astype(np.float32)
    a, b = np.asarray(op(jnp.asarray(y))), np.asarray(dense(jnp.asarray(y)))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5 * np.abs(b).max())
    ref = np.asarray(aj.reconstruct(meas, cfg, params))  # the float32 pipeline
    np.testing.assert_allclose(np.asarray(op(meas)), ref, rtol=0, atol=2e-3 * np.abs(ref).max())


def test_float32_build_has_no_factors():
    cfg = aj.preset("operator", "iso102")
    params = aj.Params.default(cfg)
    meas = aj.sample(get_material("ggx-plastic"), cfg, params, as_measurements=True)
    assert aj.compile_operator(cfg, params, meas, build_dtype=jnp.float32).factors is None


def test_default_build_is_the_host_one_and_a_trace_builds_in_jax():
    """``compile_operator``'s default build is float64 numpy (factors read off it); with traced
    parameters (under ``jit``) it builds in JAX instead, without factors, the same matrix to the
    float32 build's rounding."""
    cfg = aj.preset("operator", "iso102")
    params = aj.Params.default(cfg)
    meas = aj.sample(get_material("ggx-plastic"), cfg, params, as_measurements=True)
    op = aj.compile_operator(cfg, params, meas)
    assert op.factors is not None
    seen = []

    def build(p):
        traced = aj.compile_operator(cfg, p, meas)
        seen.append(traced.factors)
        return traced.matrix

    m = np.asarray(jax.jit(build)(params))
    assert seen == [None]
    ref = np.asarray(op.matrix)
    np.testing.assert_allclose(m, ref, rtol=0, atol=2e-3 * np.abs(ref).max())
