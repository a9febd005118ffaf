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
