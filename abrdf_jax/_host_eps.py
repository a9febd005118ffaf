"""ε of the log value spaces on the host: ``abrdf_jax._values.value_eps`` in numpy.

The JAX-free paths (the operator entry, the held-out entries, the smoothing report) take the
log of the samples with the pipeline's offset, at float32's floor.
"""

from __future__ import annotations

import numpy as np

#: The pipeline's ε offset, ``sqrt(tiny)`` of float32 (``_values.value_eps``).
EPS_FLOOR = np.finfo(np.float32).tiny ** 0.5


def sample_eps(x, log_eps: float, axis) -> np.ndarray:
    """``log_eps`` times the mean absolute value of ``x`` along ``axis``, plus the floor."""
    return x.dtype.type(log_eps) * np.mean(np.abs(x), axis=axis) + EPS_FLOOR
