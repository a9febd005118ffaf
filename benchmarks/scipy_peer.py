"""The scipy peer: the numpy/scipy implementation of the same method, run with a package setting.

The implementation is the test oracle ``tests/scipy_oracle.py`` (imported from there, so that the
peer the benchmarks time and the oracle the tests trust are one copy; run the benchmarks from the
repository root, where ``tests`` is importable). This module only maps a :class:`abrdf_jax.Config`
and :class:`abrdf_jax.Params` to the oracle's arguments.
"""

from __future__ import annotations

import numpy as np

import abrdf_jax as aj
from tests.scipy_oracle import reconstruct_scipy

__all__ = ["reconstruct_scipy", "scipy_kwargs", "reconstruct_samples"]


def scipy_kwargs(config: aj.Config, params: aj.Params) -> dict:
    """The oracle's keyword arguments for ``config`` and ``params`` (kernel, widths, λ, values, α,
    coordinates: the oracle has ``"onion"`` and ``"onion-hd"``)."""
    return dict(
        kernel=config.kernel,
        widths=tuple(np.asarray(params.widths, float)),
        smoothing=float(params.reg),
        degree=config.degree,
        value_space=config.value_space,
        alpha=params.alpha_deg,
        log_eps=config.log_eps,
        parameterization=config.parameterization,
    )


def reconstruct_samples(samples: aj.Samples, config: aj.Config, params: aj.Params) -> np.ndarray:
    """The scipy peer's ``(81, 81, 3)`` table of one material's flat samples (float64)."""
    s = samples
    return reconstruct_scipy(
        s.theta_i, s.phi_i, s.theta_v, s.phi_v, s.rgb, **scipy_kwargs(config, params)
    )
