"""Slice geometry (eq. 1) and grouping of measured samples into slices.

At an elevation pair ``(θi, θv)`` two slices are measured (Filip 2012, eq. 1):

- axial ``s_A(φi) = B(θi, θv, φi, φv = φi − α)``: the sample rotates under fixed light and camera;
- diagonal ``s_D(φv) = B(θi, θv, φi = 2π − φv + α, φv)``: light and camera move in opposite
  directions.

The axial slice is parameterized by ``φi``, the diagonal slice by ``φv``. PROTOCOL.md fixes the
protocol positions: ``φ = k · 2π / N`` with ``N = 25, 25, 26, 26`` for the pairs
``30/30, 30/75, 75/30, 75/75``.

Grouping samples into slices is :func:`abrdf_jax._grouping.group_slices`; sampling a material
along them is :mod:`abrdf_jax._sampling`.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._grid import to_vector

from ._protocol import (  # noqa: F401 - re-exported: the geometry's constants
    KINDS,
    PROTOCOL_ALPHA_DEG,
    PROTOCOL_COUNTS,
    PROTOCOL_PAIRS,
    protocol_counts,
)


def slice_angles(kind: str, param: Float[Array, "..."], alpha: Float[Array, ""]):
    """Both azimuths ``(φi, φv)`` (radians, wrapped to [0, 2π)) of slice points.

    Args:
        kind: ``"axial"`` (``param`` is φi) or ``"diagonal"`` (``param`` is φv).
        param: the slice parameter, radians.
        alpha: the slice offset α, radians.
    """
    two_pi = 2 * jnp.pi
    if kind == "axial":
        phi_i, phi_v = param, param - alpha
    elif kind == "diagonal":
        phi_i, phi_v = two_pi - param + alpha, param
    else:
        raise ValueError(f"slice kind must be one of {KINDS}, got {kind!r}")
    return jnp.mod(phi_i, two_pi), jnp.mod(phi_v, two_pi)


def protocol_parameters(counts: tuple[int, ...], nmax: int | None = None, dtype=jnp.float32):
    """Slice parameters ``t[s, k] = k · 2π / N_s`` (padded) and the counts as arrays."""
    nmax = nmax or max(max(counts), 1)
    t = np.zeros((len(counts), nmax))
    for s, n in enumerate(counts):
        if n:
            t[s, :n] = np.arange(n) * 2 * np.pi / n
    return jnp.asarray(t, dtype), jnp.asarray(counts, jnp.int32)


def slice_vectors(t, kind_index: int, pair, alpha):
    """Unit vectors ``(wi, wv)`` of positions ``t`` on one slice (``kind_index`` 0 axial, 1 diagonal)
    of the elevation pair ``pair`` (degrees); differentiable in ``alpha`` (radians) and ``t``."""
    pi_, pv = slice_angles(KINDS[kind_index], t, alpha)
    ti, tv = np.deg2rad(pair[0]), np.deg2rad(pair[1])
    return to_vector(jnp.full_like(pi_, ti), pi_), to_vector(jnp.full_like(pv, tv), pv)


def slice_directions(t, pairs, alpha):
    """Unit vectors ``(wi, wv)`` of every slice position, shapes ``(S, nmax, 3)``.

    Differentiable in ``alpha`` (radians) and ``t``.
    """
    wi, wv = zip(*(slice_vectors(t[s], s % 2, pairs[s // 2], alpha) for s in range(t.shape[0])))
    return jnp.stack(wi), jnp.stack(wv)
