"""The value map and the PCA of a prior (Nielsen, Jensen & Ramamoorthi 2015, Sec. 4), in numpy.

One copy of each step, used by :func:`~abrdf_jax.prior.train_prior`, the reconstruction and the
benchmarks' PCA peer:

1. **Log-relative map** of ABRDF values ``x = ρ cos θi`` against a reference ``x_ref`` (the
   database median per direction pair):
   ``m = ln((x cos θv + ε) / (x_ref cos θv + ε))`` (their ``ρ̂`` with ``ρ cos θi cos θv``).
2. **Training rows**: one row per material (``"joint"``: 6561·3 values, pair-major) or per
   material and channel (``"shared"``: 6561 values; one basis for R, G and B).
3. **PCA** of the centred rows ``X − μ = U Σ Vᵀ`` (``R`` rows); the components are kept *scaled*,
   ``Q = (X − μ)ᵀ U_K / √R = V_K Σ_K / √R``, so a material is ``μ + Q c`` with unit-variance
   weights ``c``. ``weights = U_K / √R`` expresses each component as a combination of the
   training rows, which evaluates the components wherever the training materials can be
   evaluated.

Everything here runs in float64 numpy (``log_relative`` and its inverse also on JAX arrays).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._errors import InputError
from .._names import PRIOR_CHANNELS

#: ε of the log-relative map in the paper.
NIELSEN_EPS = 1e-3
#: Default ε of :func:`~abrdf_jax.prior.train_prior`: chosen with the channel layout by 6-fold
#: cross-validation on the MERL train split (``python -m benchmarks.pca_peer``).
DEFAULT_EPS = 1e-6
#: Channel layouts: one basis over RGB vectors, or one basis shared by the three channels.
CHANNELS = PRIOR_CHANNELS
DEFAULT_CHANNELS = "shared"


def _xp(x):
    if isinstance(x, np.ndarray) or np.isscalar(x):
        return np
    import jax.numpy as jnp

    return jnp


def log_relative(x, ref, cos_v, eps):
    """``ln((max(x, 0) cos θv + ε) / (ref cos θv + ε))`` (numpy or JAX arrays)."""
    xp = _xp(x)
    return xp.log((xp.maximum(x, 0) * cos_v + eps) / (ref * cos_v + eps))


#: How far above its prior's ceiling (the largest mapped training value of each position, in
#: log units: 2 is a factor e² ≈ 7.4) a learned model's prediction may go before it is clipped.
#: No value of the 108 measured tables in ../shared/data (MERL and Nielsen fits, train and test)
#: exceeds the default prior's ceiling by 2; the analytic rough-grooves exceeds it on 0.12 % of
#: its cells (``python -m benchmarks.prior_ceiling``, docs/prior.md "The ceiling").
CEILING_MARGIN = 2.0


def below_ceiling(m, ceiling, margin: float = CEILING_MARGIN):
    """Mapped values ``m`` clipped at ``ceiling + margin`` (``ceiling`` broadcast against ``m``'s
    last axes; ``None``: ``m`` as it is). Where a learned model extrapolates far beyond
    everything it was trained on (an unmeasured direction of a material unlike its database),
    its prediction is bounded by its own training data instead of growing without limit."""
    if ceiling is None:
        return m
    xp = _xp(m)
    return xp.minimum(m, ceiling + margin)


def inverse_log_relative(m, ref, cos_v, eps):
    """The inverse of :func:`log_relative`, clamped at 0 (an ABRDF is non-negative)."""
    xp = _xp(m)
    return xp.maximum((xp.exp(m) * (ref * cos_v + eps) - eps) / cos_v, 0.0)


def grid_cos_view() -> np.ndarray:
    """``cos θv`` of the 6561 UBO direction pairs (illumination-major), float64."""
    from .._grid import pair_grid

    return np.cos(np.deg2rad(np.asarray(pair_grid()[2], np.float64)))


def check_channels(channels: str) -> str:
    if channels not in CHANNELS:
        raise InputError(f"channels must be one of {', '.join(CHANNELS)}, got {channels!r}")
    return channels


def median_reference(x: np.ndarray, channels: str) -> np.ndarray:
    """The reference ``x_ref`` of values ``(N, P, 3)``: the median over materials, ``(P, 3)``
    (numpy or JAX arrays).

    ``"joint"``: per position and channel; ``"shared"``: over materials and channels together,
    the same for the three channels.
    """
    xp = _xp(x)
    if check_channels(channels) == "joint":
        return xp.median(x, axis=0)
    med = xp.median(xp.moveaxis(x, -1, 1).reshape(-1, x.shape[1]), 0)
    return xp.broadcast_to(med[:, None], x.shape[1:])


def to_rows(m: np.ndarray, channels: str) -> np.ndarray:
    """Mapped values ``(N, P, 3)`` → training rows ``(N, P·3)`` joint or ``(N·3, P)`` shared
    (numpy or JAX arrays)."""
    if check_channels(channels) == "joint":
        return m.reshape(m.shape[0], -1)
    return _xp(m).moveaxis(m, -1, 1).reshape(-1, m.shape[1])


def per_position(v, channels: str):
    """A ``(P, 3)`` array in the layout of a row: ``(P·3,)`` joint, ``(P,)`` shared (channel 0)."""
    return v.reshape(-1) if check_channels(channels) == "joint" else v[:, 0]


def mapped_rows(x: np.ndarray, cos_v: np.ndarray, channels: str, eps: float, ref=None):
    """Steps 1–2: the reference (the median unless given) and the training rows of ``x``.

    Args:
        x: ``(N, P, 3)`` ABRDF values of ``N`` materials at ``P`` direction pairs.
        cos_v: ``(P,)`` or ``(P, 1)`` ``cos θv`` of the positions.
        channels, eps: the layout and ε.
        ref: ``(P, 3)`` reference; ``None``: :func:`median_reference` of ``x``.

    Returns:
        ``(ref (P, 3), rows)`` in float64.
    """
    x = np.asarray(x, np.float64)
    ref = median_reference(x, channels) if ref is None else np.asarray(ref, np.float64)
    cos_v = np.asarray(cos_v, np.float64).reshape(-1, 1)
    return ref, to_rows(log_relative(x, ref, cos_v, eps), channels)


class PCA(NamedTuple):
    """Step 3: ``mean`` ``(D,)``, scaled ``components`` ``(D, K)``, ``weights`` ``(R, K)`` (the
    components as combinations of the centred training rows), ``variances`` ``(K,)`` (the
    weights' prior variance is 1; this is ``σ_k² / R``, the variance each explains) and the
    ``rank`` of the centred rows."""

    mean: np.ndarray
    components: np.ndarray
    weights: np.ndarray
    variances: np.ndarray
    rank: int


def pca_components(rows: np.ndarray, k: int | None) -> PCA:
    """The PCA of step 3 (from the small ``R × R`` Gram matrix: ``(X − μ)(X − μ)ᵀ = U Σ² Uᵀ``).

    Args:
        rows: ``(R, D)`` training rows.
        k: number of components, ``1 ≤ k ≤ rank``; ``None`` keeps the rank.

    Raises:
        InputError: ``k`` outside ``[1, rank]`` (the message gives the rank).
    """
    rows = np.asarray(rows, np.float64)
    mean = rows.mean(0)
    centred = rows - mean
    lam2, u = np.linalg.eigh(centred @ centred.T)
    u, lam2 = u[:, ::-1], lam2[::-1]
    rank = int(np.sum(lam2 > 1e-10 * max(lam2.max(initial=0.0), 1e-300)))
    k = rank if k is None else int(k)
    if not 1 <= k <= rank:
        raise InputError(
            f"components must be in [1, {rank}] (the rank of the {rows.shape[0]} centred training "
            f"rows), got {k}"
        )
    weights = u[:, :k] / np.sqrt(rows.shape[0])
    return PCA(mean, centred.T @ weights, weights, lam2[:k] / rows.shape[0], rank)
