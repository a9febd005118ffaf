"""The fixed-parameter reconstruction as one matrix: it must equal the pipeline it was built from."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import materials
from abrdf_jax._operator import TRACE_COUNT

NAMES = ("ggx-plastic", "ward-brushed-steel", "lambert-clay")


def _material(name):
    """A material of ``materials`` as a test input: its own code broadcasts ``(3,)`` colours against
    ``(..., 1)`` shading terms, so it runs outside the strict rank promotion (conftest)."""
    mat = materials.get_material(name)

    def model(wi, wv):
        with jax.numpy_rank_promotion("allow"):
            return mat(wi, wv)

    return model


def _batch(config, params):
    meas = [aj.sample(_material(n), config, params, as_measurements=True) for n in NAMES]
    return meas, aj.stack_measurements(meas)


@pytest.mark.parametrize(
    "config",
    [
        aj.Config(budget="iso102"),  # the paper's Gaussian, linear values
        aj.Config(budget="iso102", kernel="thin_plate_spline", value_space="logsamples"),
        aj.Config(
            budget="aniso204", rule="crossing", kernel="thin_plate_spline", value_space="logsamples"
        ),
        aj.Config(budget="aniso204", rule="average"),
    ],
    ids=[
        "iso-gauss-linear",
        "iso-tps-logsamples",
        "aniso-crossing-logsamples",
        "aniso-average-linear",
    ],
)
def test_operator_equals_the_pipeline(config):
    params = aj.Params.default(config)
    meas, stacked = _batch(config, params)
    op = aj.compile_operator(config, params, meas[0])
    assert op.stage == "single" and op.matrix.shape == (
        6561,
        int(np.sum(np.asarray(meas[0].count))),
    )
    expected = aj.reconstruct_batch(meas, config, params)
    got = op(stacked)
    assert got.shape == (len(NAMES), 81, 81, 3)
    np.testing.assert_allclose(got, expected, rtol=1e-8, atol=1e-10 * float(jnp.max(expected)))
    np.testing.assert_allclose(
        op(meas[1]), expected[1], rtol=1e-8, atol=1e-10 * float(jnp.max(expected))
    )


def test_two_stage_covers_the_nonlinear_settings():
    config = aj.Config.recommended("aniso204")  # log values after a nonlinear rule
    params = aj.Params.default(config)
    meas, stacked = _batch(config, params)
    with pytest.raises(aj.InputError, match="two_stage"):
        aj.compile_operator(config, params, meas[0])
    op = aj.compile_operator(config, params, meas[0], nonlinear="two_stage")
    assert op.stage == "two_stage"
    expected = aj.reconstruct_batch(meas, config, params)
    np.testing.assert_allclose(
        op(stacked), expected, rtol=1e-7, atol=1e-9 * float(jnp.max(expected))
    )


def test_a_linear_rule_on_log_samples_takes_two_stages_when_asked():
    """``nonlinear="two_stage"`` on a linear rule on the log of the samples (the shared form of a
    folder's many small layouts, ``abrdf_jax._engine``): two stages, the same tables as the
    one-stage operator and the pipeline to rounding; on linear values the one stage stays."""
    config = aj.Config.recommended("aniso204", rule="crossing")
    params = aj.Params.default(config)
    meas, stacked = _batch(config, params)
    one = aj.compile_operator(config, params, meas[0])
    two = aj.compile_operator(config, params, meas[0], nonlinear="two_stage")
    assert (one.stage, two.stage) == ("single", "two_stage")
    expected = aj.reconstruct_batch(meas, config, params)
    for op in (one, two):
        np.testing.assert_allclose(
            op(stacked), expected, rtol=1e-7, atol=1e-9 * float(jnp.max(expected))
        )
    linear = aj.Config.recommended("aniso204", rule="crossing", value_space="linear")
    lp = aj.Params.default(linear)
    lmeas = _batch(linear, lp)[0]
    assert aj.compile_operator(linear, lp, lmeas[0], nonlinear="two_stage").stage == "single"


def test_new_values_do_not_recompile_and_bad_shapes_are_refused():
    config = aj.Config(budget="iso102", kernel="thin_plate_spline", value_space="logsamples")
    params = aj.Params.default(config)
    meas, stacked = _batch(config, params)
    op = aj.compile_operator(config, params, meas[0])
    op(stacked)
    n = TRACE_COUNT["apply"]
    scaled = aj.Measurements(
        stacked.t, stacked.y * 2.5, stacked.count, stacked.pairs, stacked.has_axial
    )
    out = op(scaled)
    assert TRACE_COUNT["apply"] == n  # same shapes, new values: no retrace
    np.testing.assert_allclose(
        out, 2.5 * op(stacked), rtol=1e-9
    )  # log space with relative ε scales exactly
    with pytest.raises(aj.InputError):
        op(jnp.ones((2, 7, 3)))


def test_large_batches_are_tiled_and_the_output_can_be_reused():
    """A batch above ``TILE`` runs tile by tile (and a last partial tile): the same tables as the
    batches of at most ``TILE`` it is made of (float32 rounding at most), the same again when it
    writes into an earlier result (``out=``, donated), and still differentiable."""
    from abrdf_jax._operator import TILE

    config = aj.Config(budget="iso102", kernel="thin_plate_spline", value_space="logsamples")
    params = aj.Params.default(config, dtype=jnp.float32)
    meas, _ = _batch(config, params)
    op = aj.compile_operator(config, params, meas[0].astype(jnp.float32))
    base = jnp.stack([op.compact(m.astype(jnp.float32)) for m in meas])  # (3, n_in, 3)
    b = 2 * TILE + 5
    scale = jax.random.uniform(jax.random.PRNGKey(0), (b, 1, 3), jnp.float32, 0.5, 2.0)
    x = base[jnp.arange(b) % 3] * scale
    big = op(x)
    pieces = jnp.concatenate([op(x[a : a + TILE]) for a in range(0, b, TILE)])
    # float32 rounding: a product of another row count may round differently, exp amplifies it
    np.testing.assert_allclose(big, pieces, rtol=1e-5, atol=1e-30)
    np.testing.assert_array_equal(op(x[TILE + 1 : TILE + 2])[0], op(x[TILE + 1])[None][0])
    earlier = op(x * 3.0)
    again = op(x, out=earlier)
    np.testing.assert_array_equal(again, big)
    assert earlier.is_deleted()  # consumed
    with pytest.raises(aj.InputError, match="out must have shape"):
        op(x, out=jnp.zeros((b, 81, 81, 2), jnp.float32))

    def loss(v, n):
        return jnp.sum(jnp.log1p(op(v[:n])))

    g_big = jax.grad(loss)(x, b)
    g_pieces = jnp.concatenate(
        [jax.grad(loss)(x[a : a + TILE], min(TILE, b - a)) for a in range(0, b, TILE)]
    )
    assert np.all(np.isfinite(g_big))
    np.testing.assert_allclose(g_big, g_pieces, rtol=1e-4, atol=1e-6 * np.abs(g_pieces).max())


def test_host_build_equals_the_jax_float64_build(monkeypatch):
    """``build_dtype="host"`` (the float64 numpy build the BTF chunk map and the command line
    use) gives the matrix of the JAX float64 build, in any working dtype; with targets it falls
    back to the JAX build."""
    from abrdf_jax import btf

    cfg = btf.default_config()  # aniso204, rule average, log samples, spike cap
    params = aj.Params.default(cfg)
    # the matrix depends on the layout only, not on the values
    meas = aj.sample(np.full((81, 81, 3), 0.2), cfg, as_measurements=True)
    ref = aj.compile_operator(cfg, params, meas, build_dtype=jnp.float64)
    from abrdf_jax import _operator

    jax_build = _operator.operator_matrix

    def refuse(*a, **k):
        raise AssertionError("the JAX build ran")

    monkeypatch.setattr(_operator, "operator_matrix", refuse)
    host = aj.compile_operator(cfg, params, meas, build_dtype="host")
    assert host.matrix.dtype == ref.matrix.dtype == jnp.float64
    np.testing.assert_allclose(host.matrix, ref.matrix, rtol=0, atol=1e-9)
    assert np.array_equal(host.keep, ref.keep) and np.array_equal(host.index, ref.index)
    low = aj.compile_operator(
        cfg, params.astype(jnp.float32), meas.astype(jnp.float32), build_dtype="host"
    )
    assert low.matrix.dtype == jnp.float32
    np.testing.assert_allclose(low.matrix, ref.matrix, rtol=0, atol=1e-6)  # float32 rounding
    monkeypatch.setattr(_operator, "operator_matrix", jax_build)
    wi = aj.to_vector(jnp.deg2rad(jnp.array([30.0])), jnp.deg2rad(jnp.array([10.0])))
    wv = aj.to_vector(jnp.deg2rad(jnp.array([45.0])), jnp.deg2rad(jnp.array([200.0])))
    at = aj.compile_operator(cfg, params, meas, build_dtype="host", targets=(wi, wv))
    assert at.matrix.shape == (1, host.matrix.shape[1])
