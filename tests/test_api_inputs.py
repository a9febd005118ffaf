"""The Python API refuses non-finite samples and impossible counts where values are concrete
(issue 16): a NaN sample would otherwise spread over the whole reconstructed table."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax.materials import get_material


@pytest.fixture(scope="module")
def measured():
    config = aj.preset("recommended", "iso102")
    params = aj.Params.default(config)
    meas = aj.sample(get_material("ggx-plastic"), config, params, as_measurements=True)
    return meas, config, params


@pytest.mark.parametrize("field", ["theta_i", "phi_i", "theta_v", "phi_v", "rgb"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_samples_with_a_non_finite_value_are_refused(field, bad):
    cols = {k: np.linspace(1.0, 2.0, 4) for k in ("theta_i", "phi_i", "theta_v", "phi_v")}
    cols["rgb"] = np.ones((4, 3))
    cols[field] = cols[field].copy()
    cols[field][2] = bad  # the third sample (all of its colour channels for rgb)
    with pytest.raises(aj.InputError, match=rf"Samples\.{field} holds \d NaN.*index \(2"):
        aj.Samples(**cols)


def test_measurements_with_a_nan_or_a_bad_count_are_refused(measured):
    meas, _, _ = measured
    y = np.asarray(meas.y).copy()
    y[1, 3, 2] = np.nan
    with pytest.raises(aj.InputError, match=r"Measurements\.y holds 1 NaN.*\(1, 3, 2\)"):
        meas.replace(y=y)
    with pytest.raises(aj.InputError, match=r"count must lie in \[0, 26\]"):
        meas.replace(count=meas.count.at[0].set(-1))
    with pytest.raises(aj.InputError, match="count must lie"):
        meas.replace(count=meas.count.at[0].set(27))


def test_inside_jit_the_check_does_not_trace_and_the_result_is_unchanged(measured):
    """Tracers are not checked (nothing concrete to check); a user's jit compiles and gives the
    eager result."""
    meas, config, params = measured
    eager = np.asarray(aj.reconstruct(meas, config, params))
    jitted = np.asarray(jax.jit(lambda m: aj.reconstruct(m, config, params))(meas))
    np.testing.assert_allclose(jitted, eager, rtol=2e-5, atol=1e-7)
    batched = jax.vmap(lambda y: aj.reconstruct(meas.replace(y=y), config, params))(
        jnp.stack([meas.y, 2 * meas.y])
    )
    np.testing.assert_allclose(np.asarray(batched[1]), 2 * eager, rtol=1e-3, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# Inside a user's jit: a run-time error, never a silent NaN table (abrdf_jax._finite)
# ---------------------------------------------------------------------------------------------

NAN_MESSAGE = "holds NaN or infinite value"
# JAX raises the runtime error as a RuntimeError, or a ValueError through a nested filter_jit: the
# message is what is promised (abrdf_jax._finite)
RUN_TIME = (RuntimeError, ValueError)


def _nan_at(y, index):
    y = np.array(y, copy=True)
    y[index] = np.nan
    return y


def test_reconstruct_in_a_jit_raises_on_a_nan_sample(measured):
    meas, config, params = measured
    f = jax.jit(lambda y: aj.reconstruct(meas.replace(y=y), config, params))
    assert np.isfinite(np.asarray(f(meas.y))).all()
    with pytest.raises(RUN_TIME, match=rf"Measurements\.y {NAN_MESSAGE}"):
        jax.block_until_ready(f(_nan_at(meas.y, (1, 3, 2))))


def test_reconstruct_batch_in_a_jit_raises_on_a_nan_sample(measured):
    meas, config, params = measured
    stacked = aj.stack_measurements([meas, meas])
    f = jax.jit(lambda y: aj.reconstruct_batch(stacked.replace(y=y), config, params))
    y = np.stack([np.asarray(meas.y), _nan_at(meas.y, (0, 0, 0))])
    with pytest.raises(RUN_TIME, match=rf"Measurements\.y {NAN_MESSAGE}"):
        jax.block_until_ready(f(y))


def test_the_operator_with_require_finite_raises_in_a_jit(measured):
    """The operator does not check on its hot path (benchmarks/finite_check.py); the documented
    guard ``op(aj.require_finite(x))`` raises at run time inside a jit, and refuses concrete
    values at once, naming them."""
    meas, _, _ = measured
    config = aj.preset("operator", "iso102")
    op = aj.compile_operator(config, aj.Params.default(config), meas)
    x = np.asarray(op.compact(meas))
    f = jax.jit(lambda x: op(aj.require_finite(x, "x")))
    np.testing.assert_allclose(np.asarray(f(x)), np.asarray(op(x)), rtol=1e-6)
    bad = _nan_at(x, (5, 1))
    with pytest.raises(RUN_TIME, match=f"x {NAN_MESSAGE}"):
        jax.block_until_ready(f(bad))
    with pytest.raises(aj.InputError, match=r"x holds 1 NaN or infinite value\(s\) \(first at "
                       r"index \(5, 1\)\)"):  # fmt: skip
        aj.require_finite(bad, "x")
    with pytest.raises(aj.InputError, match=r"^values holds 1 NaN"):  # numpy: checked at once
        op(bad)


def _sample_y(source, config, params):
    return aj.sample(source, config, params, as_measurements=True).y


def test_sample_refuses_a_nan_table_model_or_alpha(measured):
    _, config, params = measured
    table = np.full((81, 81, 3), 0.2)
    bad = _nan_at(table, (40, 2, 0))
    with pytest.raises(aj.InputError, match=r"sample: the source table holds 1 NaN or infinite "
                       r"value\(s\) \(first at index \(40, 2, 0\)\)"):  # fmt: skip
        aj.sample(bad, config, params)
    f = jax.jit(lambda t: _sample_y(t, config, params))
    assert np.isfinite(np.asarray(f(table))).all()
    with pytest.raises(RUN_TIME, match=rf"sample: the source table {NAN_MESSAGE}"):
        jax.block_until_ready(f(bad))

    def nan_model(wi, wv):
        return jnp.full((*wi.shape[:-1], 3), jnp.nan)

    with pytest.raises(RUN_TIME, match=f"sample: the model's values {NAN_MESSAGE}"):
        jax.block_until_ready(jax.jit(lambda: _sample_y(nan_model, config, params))())
    g = jax.jit(lambda a: _sample_y(table, config, aj.Params(a, params.widths, params.reg)))
    with pytest.raises(RUN_TIME, match=rf"sample: params\.alpha {NAN_MESSAGE}"):
        jax.block_until_ready(g(jnp.asarray(np.nan, params.alpha.dtype)))
