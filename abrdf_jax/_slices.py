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

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ._grid import to_vector
from ._xp import namespace

from ._protocol import (  # noqa: F401 - re-exported: the geometry's constants
    KINDS,
    PROTOCOL_ALPHA_DEG,
    PROTOCOL_COUNTS,
    PROTOCOL_PAIRS,
    protocol_counts,
)

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float


def slice_angles(kind: str, param: Float[Array, "..."], alpha: Float[Array, ""], xp=None):
    """Both azimuths ``(φi, φv)`` (radians, wrapped to [0, 2π)) of slice points.

    Args:
        kind: ``"axial"`` (``param`` is φi) or ``"diagonal"`` (``param`` is φv).
        param: the slice parameter, radians.
        alpha: the slice offset α, radians.
        xp: ``jax.numpy`` (default) or ``numpy``.
    """
    xp = namespace(xp)
    two_pi = 2 * np.pi
    if kind == "axial":
        phi_i, phi_v = param, param - alpha
    elif kind == "diagonal":
        phi_i, phi_v = two_pi - param + alpha, param
    else:
        raise ValueError(f"slice kind must be one of {KINDS}, got {kind!r}")
    return xp.mod(phi_i, two_pi), xp.mod(phi_v, two_pi)


def protocol_parameters(counts: tuple[int, ...], nmax: int | None = None, dtype="float32"):
    """Slice parameters ``t[s, k] = k · 2π / N_s`` (padded) and the counts as arrays."""
    nmax = nmax or max(max(counts), 1)
    t = np.zeros((len(counts), nmax))
    for s, n in enumerate(counts):
        if n:
            t[s, :n] = np.arange(n) * 2 * np.pi / n
    import jax.numpy as jnp

    return jnp.asarray(t, dtype), jnp.asarray(counts, jnp.int32)


def slice_vectors(t, kind_index: int, pair, alpha, xp=None):
    """Unit vectors ``(wi, wv)`` of positions ``t`` on one slice (``kind_index`` 0 axial, 1 diagonal)
    of the elevation pair ``pair`` (degrees); differentiable in ``alpha`` (radians) and ``t``
    (``xp``: ``jax.numpy`` by default, or ``numpy``)."""
    xp = namespace(xp)
    pi_, pv = slice_angles(KINDS[kind_index], t, alpha, xp)
    ti, tv = np.deg2rad(pair[0]), np.deg2rad(pair[1])
    return to_vector(xp.full_like(pi_, ti), pi_, xp), to_vector(xp.full_like(pv, tv), pv, xp)


def slice_directions(t, pairs, alpha):
    """Unit vectors ``(wi, wv)`` of every slice position, shapes ``(S, nmax, 3)``.

    Differentiable in ``alpha`` (radians) and ``t``.
    """
    import jax.numpy as jnp

    wi, wv = zip(*(slice_vectors(t[s], s % 2, pairs[s // 2], alpha) for s in range(t.shape[0])))
    return jnp.stack(wi), jnp.stack(wv)
