"""The JAX pipeline against the independent numpy/scipy implementation ``tests/scipy_oracle.py`` (float64)."""

import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from tests.scipy_oracle import reconstruct_scipy


def model(wi, wv):
    """A glossy, anisotropic, non-reciprocal test material."""
    r = jnp.stack([-wi[..., 0], -wi[..., 1], wi[..., 2]], -1)
    lobe = jnp.exp(4.0 * (jnp.sum(r * wv, -1) - 1.0)) * (
        1.0 + 0.5 * wi[..., 0] ** 2 - 0.2 * wv[..., 1]
    )
    v = 0.1 + lobe
    return jnp.stack([v, 0.9 * v, 0.7 * v], -1) * wi[..., 2:3]


@pytest.mark.parametrize(
    "budget,kernel,value_space,parameterization",
    [
        ("iso102", "gaussian", "linear", "onion"),
        ("aniso204", "gaussian", "linear", "onion"),
        ("aniso204", "thin_plate_spline", "log", "onion"),
        ("iso102", "multiquadric", "log", "onion"),
        ("iso102", "thin_plate_spline", "logsamples", "onion"),
        ("aniso204", "thin_plate_spline", "logsamples", "onion"),
        ("iso102", "thin_plate_spline", "logsamples", "onion-hd"),
        ("aniso204", "thin_plate_spline", "logsamples", "onion-hd"),
        ("aniso204", "gaussian", "linear", "onion-hd"),
    ],
)
def test_jax_matches_scipy_peer(budget, kernel, value_space, parameterization):
    # the scipy oracle has no slice smoothing (tests/test_smoothing.py tests it against the pipeline)
    cfg = aj.Config(
        budget=budget,
        kernel=kernel,
        value_space=value_space,
        slice_smoothing=None,
        parameterization=parameterization,
    )
    p = aj.Params(jnp.deg2rad(15.0), jnp.asarray([0.6, 0.5, 0.7, 0.6]), jnp.asarray(1e-3))
    s = aj.sample(model, cfg, p).to_numpy()
    meas, _ = aj.group_slices(s, dtype=np.float64)
    ours = np.asarray(aj.reconstruct(meas, cfg, p))
    peer = reconstruct_scipy(
        s.theta_i,
        s.phi_i,
        s.theta_v,
        s.phi_v,
        s.rgb,
        kernel=kernel,
        widths=np.asarray(p.widths),
        smoothing=1e-3,
        value_space=value_space,
        parameterization=parameterization,
    )
    np.testing.assert_allclose(ours, peer, rtol=1e-7, atol=1e-9)
