"""The measured pairs' residual curves: what the bivariate model misses where it was measured.

The bivariate model (:mod:`abrdf_jax._bivariate`) reads a material as a function of ``(θh, θd)``
alone; a real one also varies with ``φd``, so at an elevation pair that was measured its fit
leaves a residual along the slices (in the log of the BRDF), which a dense capture resolves
and the thin-plate spline, pooling the pairs in one plane, smooths away. At the pair's own
elevations an isotropic material is a function of the relative azimuth ``Δφ = φi − φv`` only,
which the pair's diagonal slice covers whole: the residual of the pair's samples, interpolated
over ``Δφ`` (linear, periodic; samples at one ``Δφ`` averaged), is the correction at every
target of that pair. Elsewhere each pair's curve is weighted by a Gaussian in ``(θi, θv)`` of
width :data:`PAIR_WIDTH_DEG` around it, the weights divided by their sum where it exceeds 1: so
a target between measured pairs takes a blend of their curves and one far from all of them
(``θ = 0``, say) little of any. Linear in the residuals, so the whole model stays one matrix.

The width is the best of 5°, 10°, 15°, 20° and 30° on the MERL train split (protocol and
100-sample captures: 15°; docs/captures.md). Numpy only.
"""

from __future__ import annotations

import numpy as np

from ._grid import from_vector
from ._grouping import infer_pairs
from ._groups import cell_means, tolerance_groups

#: Width (degrees) of the Gaussian in ``(θi, θv)`` that carries a measured pair's residual curve
#: to the targets around it (module docstring); ``0`` turns the correction off.
PAIR_WIDTH_DEG = 15.0


def _periodic_index(knots: np.ndarray, x: np.ndarray, period: float):
    """``(lo, hi, frac)``, each ``(len(x),)``: the periodic linear interpolation of sorted
    distinct ``knots`` at ``x`` is ``(1 − frac) v[lo] + frac v[hi]`` (one knot: constant)."""
    m = len(knots)
    if m == 1:
        zero = np.zeros(len(x), np.int64)
        return zero, zero, np.zeros(len(x))
    hi = np.searchsorted(knots, x, side="right") % m  # the next knot (wrapping past the last)
    lo = (hi - 1) % m
    gap = (knots[hi] - knots[lo]) % period
    gap = np.where(gap > 0, gap, period)
    return lo, hi, ((x - knots[lo]) % period) / gap


def _azimuth_knots(dphi_src: np.ndarray):
    """``(knots, which, count)``: the distinct ``Δφ`` of the sources (to 1e-6°, sorted; each the
    mean of its sources), each source's knot and each knot's number of sources."""
    _, which, count = tolerance_groups(dphi_src, 1e-6)
    return cell_means(dphi_src[:, None], which, count)[:, 0], which, count


def _azimuth_curve(dphi_src: np.ndarray, dphi_dst: np.ndarray) -> np.ndarray:
    """``(q, n)``: the periodic linear interpolation over ``Δφ`` (degrees) of values at the
    sources (those at one ``Δφ``, to 1e-6°, averaged), at the targets."""
    knots, which, count = _azimuth_knots(dphi_src)
    lo, hi, frac = _periodic_index(knots, dphi_dst, 360.0)
    w = np.zeros((len(dphi_dst), len(knots)))
    rows = np.arange(len(dphi_dst))
    w[rows, lo] += 1.0 - frac
    w[rows, hi] += frac
    return w[:, which] / count[which][None, :]


def _azimuth_values(dphi_src: np.ndarray, values: np.ndarray, dphi_dst: np.ndarray) -> np.ndarray:
    """``(q, C)``: :func:`_azimuth_curve` applied to ``values`` ``(n, C)`` without its
    ``(q, n)`` matrix (memory ``O(q + n)``: any number of sources)."""
    knots, which, count = _azimuth_knots(dphi_src)
    at = cell_means(values, which, count)
    lo, hi, frac = _periodic_index(knots, dphi_dst, 360.0)
    return (1.0 - frac)[:, None] * at[lo] + frac[:, None] * at[hi]


def target_angles(wi, wv) -> np.ndarray:
    """``(q, 3)``: ``θi``, ``θv`` and ``Δφ = φi − φv`` (degrees, ``Δφ`` in ``[0, 360)``) of
    direction pairs ``(q, 3)``: what :func:`pair_residual_matrix` reads of its targets."""
    ti, pi_ = from_vector(np.asarray(wi, np.float64), np)
    tv, pv = from_vector(np.asarray(wv, np.float64), np)
    return np.stack([np.rad2deg(ti), np.rad2deg(tv), np.rad2deg(pi_ - pv) % 360.0], -1)


def _pair_weights(src: np.ndarray, dst: np.ndarray, width_deg: float, pairs):
    """``(index, g)``: each source's measured pair (``-1``: none) and each pair's Gaussian at
    the targets ``(q, P)``, the weights divided by their sum where it exceeds 1; ``None`` when
    there is no correction (``width_deg`` 0, no pair)."""
    if not width_deg > 0:
        return None
    pairs, index = infer_pairs(src[:, 0], src[:, 1]) if pairs is None else pairs
    if not pairs:
        return None
    p = np.asarray(pairs, np.float64)
    d2 = (dst[:, 0:1] - p[None, :, 0]) ** 2 + (dst[:, 1:2] - p[None, :, 1]) ** 2
    g = np.exp(-d2 / (2.0 * width_deg**2))  # (q, P)
    g /= np.maximum(g.sum(axis=1, keepdims=True), 1.0)
    return np.asarray(index), g


def _pair_parts(src_wi, src_wv, dst: np.ndarray, width_deg: float, pairs):
    """The sources' :func:`target_angles` ``(n, 3)`` and, for each measured pair with sources,
    ``(idx, weight)``: its sources' indices and its Gaussian weight at the targets ``(q, 1)``
    (none where there is no correction)."""
    src = target_angles(src_wi, src_wv)
    found = _pair_weights(src, dst, width_deg, pairs)
    if found is None:
        return src, []
    index, g = found
    parts = [(np.nonzero(index == k)[0], g[:, k : k + 1]) for k in range(g.shape[1])]
    return src, [(idx, w) for idx, w in parts if len(idx)]


def pair_residual_matrix(
    src_wi, src_wv, dst: np.ndarray, width_deg: float = PAIR_WIDTH_DEG, pairs=None
):
    """The correction at the targets as a map ``(q, n)`` of the residuals at the sources
    (module docstring): ``Σ_k g_k ρ_k(Δφ) / max(1, Σ_k g_k)``, ``ρ_k`` the residual curve of
    measured pair ``k``, ``g_k`` its Gaussian at the target.

    Args:
        src_wi, src_wv: the sources' unit vectors ``(n, 3)``.
        dst: the targets' :func:`target_angles` ``(q, 3)``.
        width_deg: :data:`PAIR_WIDTH_DEG`; ``0`` gives the zero map.
        pairs: ``(pairs, index)``: the elevation pairs ``(θi, θv)`` (degrees) and each source's
            pair (``-1``: none), where a grouping knows them (the command line's slices);
            ``None``: :func:`abrdf_jax._grouping.infer_pairs` on the sources' elevations (stray
            sources take no part).
    """
    src, parts = _pair_parts(src_wi, src_wv, dst, width_deg, pairs)
    out = np.zeros((len(dst), len(src)))
    for idx, weight in parts:
        curve = _azimuth_curve(src[idx, 2], dst[:, 2])
        curve *= weight
        out[:, idx] = curve
    return out


def pair_residual_values(
    src_wi, src_wv, residual: np.ndarray, dst: np.ndarray, width_deg=PAIR_WIDTH_DEG, pairs=None
) -> np.ndarray:
    """``pair_residual_matrix(src_wi, src_wv, dst, width_deg, pairs) @ residual`` ``(q, C)``
    for residuals ``(n, C)`` at the sources, without the ``(q, n)`` matrix: what one
    measurement of any size needs (:func:`abrdf_jax.reconstruct_bivariate`)."""
    src, parts = _pair_parts(src_wi, src_wv, dst, width_deg, pairs)
    out = np.zeros((len(dst), residual.shape[1]))
    for idx, weight in parts:
        out += weight * _azimuth_values(src[idx, 2], residual[idx], dst[:, 2])
    return out
