"""Smooth look-up of an ABRDF table at any direction pair, numpy only (no JAX, no Mitsuba).

Each direction gets four ``(UBO index, weight)`` pairs: linear in θ between the two UBO rings
that bracket it (clamped at the 75° ring) and linear in φ between the two neighbours on each
ring (the normal is one point). At a grid direction the weights are ``(1, 0, 0, 0)``, so grid
values are reproduced exactly. What is interpolated is the BRDF, ``table / cos θi`` of the grid
light direction, and the result is multiplied by the true ``cos θi`` again: a UBO value already
holds ``cos θ`` of the light (``io._tables``), so this applies it exactly once and lets the
value fall to 0 at the horizon instead of repeating the 75° ring's value.
"""

from __future__ import annotations

import numpy as np

from .._protocol import UBO_COUNTS, UBO_THETAS_DEG

_STARTS = np.concatenate([[0], np.cumsum(UBO_COUNTS)[:-1]])
_COUNTS = np.asarray(UBO_COUNTS)
_STEP = UBO_THETAS_DEG[1] - UBO_THETAS_DEG[0]
_LAST = len(UBO_THETAS_DEG) - 1


def _ring_pairs(ring, phi_deg):
    n = _COUNTS[ring]
    s = phi_deg / (360.0 / n)
    j = np.floor(s)
    f = s - j
    j = j.astype(int) % n
    return _STARTS[ring] + j, _STARTS[ring] + (j + 1) % n, 1.0 - f, f


def direction_weights(w) -> tuple[np.ndarray, np.ndarray]:
    """``(index, weight)``, each ``(..., 4)``, of local directions ``w`` ``(..., 3)`` over the
    UBO grid (``z`` the normal, ``x`` the tangent, ``φ = atan2(y, x)`` as in ``abrdf_jax._grid``)."""
    w = np.asarray(w, dtype=np.float64)
    norm = np.linalg.norm(w, axis=-1)
    z = np.clip(w[..., 2] / np.where(norm > 0, norm, 1.0), -1.0, 1.0)
    theta = np.minimum(np.degrees(np.arccos(z)), UBO_THETAS_DEG[-1])
    phi = np.mod(np.degrees(np.arctan2(w[..., 1], w[..., 0])), 360.0)
    k = np.minimum(np.floor(theta / _STEP).astype(int), _LAST - 1)
    t = np.clip(theta / _STEP - k, 0.0, 1.0)
    a0, a1, wa0, wa1 = _ring_pairs(k, phi)
    b0, b1, wb0, wb1 = _ring_pairs(k + 1, phi)
    index = np.stack([a0, a1, b0, b1], axis=-1)
    weight = np.stack([(1 - t) * wa0, (1 - t) * wa1, t * wb0, t * wb1], axis=-1)
    return index, weight


def brdf_of(table) -> np.ndarray:
    """The BRDF ``table[..., i, v, :] / cos θi`` (float64), what :func:`lookup` interpolates."""
    theta = np.repeat(np.asarray(UBO_THETAS_DEG), _COUNTS)
    return np.asarray(table, np.float64) / np.cos(np.radians(theta))[:, None, None]


def lookup(brdf, wl, wv, texel=None) -> np.ndarray:
    """The table value (BRDF · cos θ of the light) at light ``wl`` and view ``wv`` ``(..., 3)``.

    Args:
        brdf: :func:`brdf_of` of a table ``(81, 81, 3)`` or of a BTF ``(H, W, 81, 81, 3)``.
        wl, wv: local light and view directions.
        texel: for a BTF, ``(row, column)`` integer arrays broadcast with the directions.

    Returns:
        ``(..., 3)``; 0 where either direction is at or below the horizon.
    """
    wl, wv = np.asarray(wl, np.float64), np.asarray(wv, np.float64)
    il, gl = direction_weights(wl)
    iv, gv = direction_weights(wv)
    if texel is None:
        vals = brdf[il[..., :, None], iv[..., None, :]]
    else:
        r, c = (np.asarray(x)[..., None, None] for x in texel)
        vals = brdf[r, c, il[..., :, None], iv[..., None, :]]
    out = np.einsum("...a,...b,...abc->...c", gl, gv, vals)
    cos_l = wl[..., 2] / np.maximum(np.linalg.norm(wl, axis=-1), 1e-300)
    up = (wl[..., 2] > 0) & (wv[..., 2] > 0)
    return np.where(up[..., None], out * np.maximum(cos_l, 0.0)[..., None], 0.0)
