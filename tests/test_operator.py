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
