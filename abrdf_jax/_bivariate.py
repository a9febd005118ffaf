"""A bivariate model of an isotropic material: its values as a function of ``(θh, θd)`` alone.

Romeiro, Vasilyev and Zickler (2008, "Passive reflectometry", ECCV) observed that measured
isotropic BRDFs are well approximated by functions of the half angle ``θh`` and the
difference angle ``θd`` (Rusinkiewicz 1998) alone: the dependence on ``φd`` is weak. In those
two angles the samples of the protocol's slices lie on curves (a diagonal slice of the pair
``(θ, θ)`` runs from ``(θh, θd) = (0, θ)`` at the mirror direction to ``(θ, 0)`` at the
retro-reflection), and a pair that was never measured, ``(45°, 45°)`` say, lies *between*
those curves: the fill across elevations is an interpolation in the plane the curves sweep,
not an extrapolation along the elevation axes as in the onion coordinates of the RBF.

The fit: a thin-plate spline in 2-D (degree-1 polynomial, ridge ``smoothing`` on the kernel's
diagonal) of ``ln(max(y / cos θi, 0) + ε)`` (the BRDF: the protocol's values carry
``cos θi``) at the coordinates ``(√(θh / (π/2)), θd / (π/2))`` (the square-root warp of θh
that MERL's tables use, which spreads the specular peak), evaluated at the targets, then
``exp``, minus ``ε``, times ``cos θi`` of the target, clamped at 0. ``ε`` is
``log_eps · mean |y / cos θi|`` per channel (as ``Config.log_eps``). What the plane cannot hold
is kept where it was measured: the spline's residual along each measured pair's slices,
interpolated over ``Δφ``, corrects that pair's targets and, through a Gaussian in ``(θi, θv)``,
those around it (:mod:`abrdf_jax._pair_residual`). It is linear in the log samples: one matrix
per sample layout (:func:`bivariate_map`, what the command line and BTF chunks apply to many
measurements), or, for one measurement (:func:`reconstruct_bivariate`), the same map applied
in factors (:func:`bivariate_values`: no matrix with a row per target and a column per sample,
so memory and time grow linearly with a continuous capture's samples). The samples are used at
their recorded directions, whatever the slices, pairs, gaps or offsets; more than
:data:`abrdf_jax._tps.MAX_POINTS` are averaged in cells of the plane first (for the spline,
:mod:`abrdf_jax._tps`; the residual curves read every sample).

It assumes isotropy (an anisotropic material's ``φ`` dependence is lost away from the measured
pairs) and reciprocity; it is numpy only (no JAX). Measured by ``python -m benchmarks.bivariate`` (docs/captures.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import ClassVar

import numpy as np

from ._errors import InputError
from ._groups import tolerance_groups
from ._grid import half_diff, to_vector, ubo_grid
from ._host_eps import EPS_FLOOR
from ._memo import BoundedMemo
from . import _tps
from ._pair_residual import (
    PAIR_WIDTH_DEG,
    pair_residual_matrix,
    pair_residual_values,
    target_angles,
)

#: Ridge λ on the thin-plate kernel's diagonal (log units squared): the best of 1e-5, 1e-3 and
#: 1e-1 on the MERL train split (``python -m benchmarks.bivariate``'s sweep; the others 3–9 %
#: worse).
SMOOTHING = 1e-3
#: ``ε = LOG_EPS · mean |y / cos θi|`` per channel: the floor of the log (as ``Config.log_eps``,
#: whose 1e-2 is 5 % worse here on the same sweep; 1e-4 is level with 1e-3).
LOG_EPS = 1e-3


def bivariate_coordinates(wi: np.ndarray, wv: np.ndarray) -> np.ndarray:
    """``(√(θh / (π/2)), θd / (π/2))`` of direction pairs ``(..., 3)``: ``(..., 2)`` in ``[0, 1]``."""
    hd = half_diff(np.asarray(wi, np.float64), np.asarray(wv, np.float64), np)
    return np.stack(
        [np.sqrt(np.maximum(hd[..., 0], 0.0) / (math.pi / 2)), hd[..., 2] / (math.pi / 2)], -1
    )


def bivariate_matrix(src: np.ndarray, dst: np.ndarray, smoothing: float = SMOOTHING) -> np.ndarray:
    """The map ``(q, n)`` from values at the points ``src`` ``(n, 2)`` to the thin-plate spline's
    values at ``dst`` ``(q, 2)`` (float64; module docstring). A degree-1 polynomial is
    reproduced exactly: each row sums to 1."""
    fit = _tps.fit(src, smoothing)
    return _tps.basis(dst, fit.centres) @ fit.coef()


def bivariate_map(
    src_wi,
    src_wv,
    targets=None,
    smoothing: float = SMOOTHING,
    pair_width: float = PAIR_WIDTH_DEG,
    pairs=None,
) -> np.ndarray:
    """The model's map ``(q, n)`` of the log BRDF from sources (unit vectors ``(n, 3)``) to
    ``targets`` (``(wi, wv)``, each ``(q, 3)``; ``None``: the UBO grid, whose coordinates are
    made once): the spline of :func:`bivariate_matrix` plus the measured pairs' residual curves
    (:func:`abrdf_jax._pair_residual.pair_residual_matrix`, width ``pair_width`` degrees; 0:
    the spline alone; ``pairs``: the sources' elevation pairs where a grouping knows them),
    ``(B_dst − C B_src) coef + C``."""
    src = bivariate_coordinates(src_wi, src_wv)
    fit = _tps.fit(src, smoothing)
    coef = fit.coef()
    dst, at, angles = _target_points(targets)
    out = (_tps.basis(dst, fit.centres) @ coef)[at]
    if not pair_width > 0:
        return out
    corr = pair_residual_matrix(src_wi, src_wv, angles, pair_width, pairs)
    if len(src) <= _tps.MAX_POINTS:  # the spline at its own points, (n, n): one product fewer
        out -= corr @ (_tps.basis(src, fit.centres) @ coef)
    else:  # binned: no (n, n) matrix; in place, so that a large capture holds three (q, n)
        out -= (corr @ _tps.basis(src, fit.centres)) @ coef
    out += corr
    return out


def bivariate_values(
    src_wi,
    src_wv,
    z: np.ndarray,
    targets=None,
    smoothing: float = SMOOTHING,
    pair_width: float = PAIR_WIDTH_DEG,
    pairs=None,
) -> np.ndarray:
    """``bivariate_map(src_wi, src_wv, targets, smoothing, pair_width, pairs) @ z`` ``(q, K)``
    for values ``z`` ``(n, K)`` at the sources, float64, without any ``(q, n)`` or ``(n, n)``
    matrix: the spline's coefficients of ``z``, its values at the targets and its residual at
    the sources (:data:`abrdf_jax._tps.ROWS` rows of the basis at a time), the residual
    curves' values (:func:`abrdf_jax._pair_residual.pair_residual_values`). Memory ``O((q + n) K)`` beside the
    fit's ``O(m²)``: one measurement of any size (:func:`reconstruct_bivariate`)."""
    z = np.asarray(z, np.float64)
    src = bivariate_coordinates(src_wi, src_wv)
    fit = _tps.fit(src, smoothing)
    a = fit.coef_of(z)
    dst, at, angles = _target_points(targets)
    out = _tps.basis_times(dst, fit.centres, a)[at]
    if pair_width > 0:
        residual = z - _tps.basis_times(src, fit.centres, a)
        out += pair_residual_values(src_wi, src_wv, residual, angles, pair_width, pairs)
    return out


def _target_points(targets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(points, at, angles)``: the targets' distinct bivariate coordinates ``(u, 2)``, each
    target's point ``(q,)`` and the targets' :func:`target_angles` ``(q, 3)`` (``None``: the UBO
    grid's, made once). The spline depends on the coordinates alone, and many direction pairs
    share them (the grid's 6561 pairs have 384 ``(θh, θd)``): it is evaluated once a point."""
    if targets is None:
        return _grid_targets()
    return (*_distinct(bivariate_coordinates(*targets)), target_angles(*targets))


#: Coordinates closer than this (per axis, in ``[0, 1]``) are one point of the spline.
POINT_TOL = 1e-9


def _distinct(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``points`` ``(q, 2)`` (to :data:`POINT_TOL`; each the first of its
    kind) and each row's index among them."""
    first, at, _ = tolerance_groups(points, POINT_TOL)
    return points[first], at


def checked_angles(get, where: str) -> tuple[np.ndarray, ...]:
    """``(θi, φi, θv, φv)`` in radians of the sample angles ``get(name)`` (degrees; ``name`` in
    ``theta_i, phi_i, theta_v, phi_v``), checked: one shape ``(n,)``, ``n ≥ 3``, finite, ``θi <
    90°`` (the values divide by ``cos θi``). ``where`` names them in errors."""
    names = ("theta_i", "phi_i", "theta_v", "phi_v")
    cols = [np.asarray(get(k), np.float64) for k in names]
    n = cols[0].shape
    if len(n) != 1 or n[0] < 3 or any(c.shape != n for c in cols):
        raise InputError(
            f"{where}: expected at least 3 samples, angles of one length >= 3, shape (n,); got "
            f"{[c.shape for c in cols]}"
        )
    for name, c in zip(names, cols):
        if not np.all(np.isfinite(c)):
            raise InputError(f"{where}.{name} has non-finite values")
    if np.any(cols[0] >= 90.0):
        raise InputError(f"{where}.theta_i must be below 90 degrees (the values divide by cos θi)")
    return tuple(np.deg2rad(cols))


def source_vectors(ti, pi_, tv, pv) -> tuple[np.ndarray, np.ndarray]:
    """The unit vectors ``(wi, wv)``, each ``(n, 3)``, of sample angles in radians."""
    return to_vector(ti, pi_, np), to_vector(tv, pv, np)


def _columns(samples) -> tuple[np.ndarray, ...]:
    """``(θi, φi, θv, φv)`` in radians and ``rgb`` of :class:`~abrdf_jax.Samples` (or anything
    with those fields in degrees, e.g. ``io.read_sample_columns``'s), checked."""
    try:
        angles = checked_angles(lambda k: getattr(samples, k), "samples")
        rgb = np.asarray(samples.rgb, np.float64)
    except AttributeError as e:
        raise InputError(
            f"samples must be Samples (theta_i, phi_i, theta_v, phi_v, rgb): {e}"
        ) from None
    if rgb.shape != (*angles[0].shape, 3):
        raise InputError(f"samples: expected rgb of shape (n, 3), got {rgb.shape}")
    if not np.all(np.isfinite(rgb)):
        raise InputError("samples.rgb has non-finite values")
    return (*angles, rgb)


@functools.lru_cache(maxsize=1)
def _grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The UBO grid's ``(wi, wv)`` ``(6561, 3)`` and ``cos θi`` ``(6561,)``, once."""
    theta, phi = (np.deg2rad(np.asarray(a, np.float64)) for a in ubo_grid())
    ti, tv = np.meshgrid(theta, theta, indexing="ij")
    pi_, pv = np.meshgrid(phi, phi, indexing="ij")
    wi, wv = to_vector(ti, pi_, np).reshape(-1, 3), to_vector(tv, pv, np).reshape(-1, 3)
    return wi, wv, wi[:, 2]


@functools.lru_cache(maxsize=1)
def _grid_targets() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The UBO grid's :func:`_target_points`: its distinct bivariate coordinates, each pair's
    index among them ``(6561,)`` and its target angles ``(6561, 3)``."""
    wi, wv, _ = _grid()
    return (*_distinct(bivariate_coordinates(wi, wv)), target_angles(wi, wv))


def log_brdf(x, cos_src, log_eps: float, xp=np):
    """``(z, ε)``: the log BRDF ``ln(max(x / cos θi, 0) + ε)`` of the ABRDF values ``x``
    ``(B, n, C)`` at sources with ``cos θi`` ``cos_src`` ``(n,)``, and ``ε`` ``(B, 1, C)``
    (``log_eps`` times the mean ``|x / cos θi|`` per member and channel, plus the floor of
    :mod:`abrdf_jax._host_eps`). ``xp``: numpy (here) or ``jax.numpy`` (BTF chunks)."""
    brdf = x / cos_src[None, :, None]
    eps = log_eps * xp.mean(xp.abs(brdf), axis=1, keepdims=True) + EPS_FLOOR
    return xp.log(xp.maximum(brdf, 0.0) + eps), eps


def from_log(lin, eps, cos_dst, xp=np):
    """The ABRDF values ``max((exp(lin) − ε) cos θi, 0)`` of the log BRDF ``lin`` ``(B, q, C)``
    at targets with ``cos θi`` ``cos_dst`` ``(q,)`` (the inverse of :func:`log_brdf`)."""
    return xp.maximum((xp.exp(lin) - eps) * xp.maximum(cos_dst, 0.0)[None, :, None], 0.0)


def _values(matrix, x, cos_src, cos_dst, log_eps: float) -> np.ndarray:
    """The model's map on the samples' values ``x`` ``(B, n, C)``: :func:`log_brdf`, the log
    BRDF through ``matrix`` ``(q, n)``, :func:`from_log`; float32 ``(B, q, C)``, C-contiguous.

    The samples' log in float64, the product and what follows in float32 (as the RBF operator:
    a row of the map has an absolute sum of a few units, so its rounding stays near 1e-6 of the
    log), all B·C rows in one product: the cost of a folder's large batches. The product is
    material-major, ``(B·C, n) @ (n, q)``, so each table is one contiguous block: a
    direction-major product (``(q, n) @ (n, B·C)``) left every table strided across the
    batch, and the finiteness check and each table's write gathered it again (ten times
    the cost of this layout's final in-cache transpose; docs/notes.md, 28th session)."""
    b, n, c = x.shape
    z, eps = log_brdf(x, cos_src, log_eps)
    rows = np.ascontiguousarray(z.astype(np.float32).transpose(0, 2, 1)).reshape(b * c, n)
    lin = (rows @ np.asarray(matrix, np.float32).T).reshape(b, c, -1)  # (B, C, q)
    np.exp(lin, out=lin)  # from_log, in place: (exp(lin) − ε) cos θi, clamped at 0
    lin -= eps.astype(np.float32).transpose(0, 2, 1)
    lin *= np.maximum(cos_dst, 0.0).astype(np.float32)
    out = np.empty((b, lin.shape[-1], c), np.float32)
    return np.maximum(lin.transpose(0, 2, 1), 0.0, out=out)


def reconstruct_bivariate(
    samples,
    *,
    targets=None,
    smoothing: float = SMOOTHING,
    log_eps: float = LOG_EPS,
    pair_width: float = PAIR_WIDTH_DEG,
) -> np.ndarray:
    """Reconstruct an isotropic material as a function of ``(θh, θd)`` (module docstring).

    Args:
        samples: the measurement, :class:`~abrdf_jax.Samples` (any slices, pairs and offsets:
            each sample is used at its own direction).
        targets: ``(wi, wv)`` unit vectors ``(q, 3)`` to evaluate at; default the UBO grid.
        smoothing: the ridge λ of the thin-plate fit (:data:`SMOOTHING`).
        log_eps: ``ε`` of the log, relative to the mean value (:data:`LOG_EPS`).
        pair_width: the width (degrees) that carries the measured pairs' residual curves
            (:mod:`abrdf_jax._pair_residual`, :data:`PAIR_WIDTH_DEG`); 0: the spline alone.

    Returns:
        float32 ``(81, 81, 3)`` ABRDF table (``(q, 3)`` for ``targets``), ``≥ 0``.

    Raises:
        InputError: fewer than 3 samples, non-finite values, ``θi ≥ 90°``, a bad ``targets``,
            ``smoothing < 0``, ``log_eps ≤ 0`` or ``pair_width < 0``, or too few distinct
            samples for the fit.
    """
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise InputError(f"smoothing must be a finite number >= 0, got {smoothing!r}")
    if not (np.isfinite(log_eps) and log_eps > 0):
        raise InputError(f"log_eps must be a finite number > 0, got {log_eps!r}")
    if not (np.isfinite(pair_width) and pair_width >= 0):
        raise InputError(f"pair_width must be a finite number >= 0, got {pair_width!r}")
    ti, pi_, tv, pv, rgb = _columns(samples)
    if targets is None:
        cos_dst = _grid()[2]
    else:
        targets = tuple(np.asarray(t, np.float64) for t in targets)
        wi_t, wv_t = targets
        if wi_t.ndim != 2 or wi_t.shape[-1] != 3 or wv_t.shape != wi_t.shape:
            raise InputError(f"targets must be two (q, 3) arrays; got {wi_t.shape}, {wv_t.shape}")
        cos_dst = wi_t[:, 2]
    wi, wv = source_vectors(ti, pi_, tv, pv)
    out = _one(wi, wv, rgb, cos_dst, targets, smoothing, log_eps, pair_width=pair_width)
    return out.reshape(81, 81, 3) if targets is None else out


def _one(wi, wv, x, cos_dst, targets=None, smoothing=SMOOTHING, log_eps=LOG_EPS, **kw):
    """The model's table ``(q, C)`` float32 of one measurement's ABRDF values ``x`` ``(n, C)`` at
    the sources ``(wi, wv)``: :func:`log_brdf`, :func:`bivariate_values` (the map in factors,
    float64), :func:`from_log`. ``kw``: ``pair_width``, ``pairs``."""
    z, eps = log_brdf(np.asarray(x, np.float64)[None], wi[:, 2], log_eps)
    lin = bivariate_values(wi, wv, z[0], targets, smoothing, **kw)
    return from_log(lin[None], eps, cos_dst)[0].astype(np.float32)


# --------------------------------------------------------------------------------------------
# The command line's model (``reconstruct --model bivariate``): one map per slice layout
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class BivariateModel:
    """The bivariate model of one budget, what the command line passes to
    :func:`abrdf_jax._engine.reconstruct_many` in place of a :class:`~abrdf_jax.Config`
    (``operator_only``: one map per slice layout). It reads the grouped slices at the recorded
    directions of their samples (``SliceArrays.directions``, as the library's
    :func:`reconstruct_bivariate` reads its samples; slices without them, a
    :class:`~abrdf_jax.Measurements`, at their projected positions); ``iso102`` reads the
    diagonal slices only, ``aniso204`` all of them."""

    budget: str
    name: ClassVar[str] = "bivariate"
    operator_only: ClassVar[bool] = True

    @staticmethod
    def layout_key(meas) -> str:
        """:func:`abrdf_jax._grouping.layout_key` and the slots' recorded directions: what one
        map serves (two jittered captures whose projections agree are still two layouts)."""
        import hashlib

        from ._grouping import layout_key

        d = getattr(meas, "directions", None)
        if d is None:
            return layout_key(meas)
        valid = np.arange(d.shape[1])[None, :] < np.asarray(meas.count)[:, None]
        h = hashlib.sha256(layout_key(meas).encode())
        h.update(np.where(valid[..., None, None], d, 0.0).astype(np.float32).tobytes())
        return h.hexdigest()

    def operator(self, params, template, store=None, warn=None, before_build=None):
        """The apply function of ``template``'s layout: stacked slice values ``(B, S, nmax, C)``
        → ``(B, 81, 81, C)`` float32 (:func:`_layout_apply`; store arguments accepted and
        unused: a build is one small solve)."""
        from ._prior_operator import slice_counts  # iso102: the axial slices' counts 0

        count = tuple(int(c) for c in slice_counts(template, self.budget))
        alpha = float(np.asarray(params.alpha))
        key = (self.budget, alpha, count, self.layout_key(template))
        return _APPLIES.get(key, lambda: _layout_apply(template, alpha, np.asarray(count)))


#: The maps of the layouts met in this process (a folder's layouts are built once).
_APPLIES = BoundedMemo(16)


def _directions(template, pairs, alpha: float, count) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wv)`` ``(n, 3)`` of the slots read (``count`` per slice): the recorded ones where
    the slices carry them, else the slice positions' (:func:`abrdf_jax._slices.slice_vectors`)."""
    from ._slices import slice_vectors

    d = getattr(template, "directions", None)
    if d is not None:
        rows = np.concatenate([np.asarray(d[s, :c], np.float64) for s, c in enumerate(count)])
        return rows[:, 0], rows[:, 1]
    t = np.asarray(template.t, np.float64)
    parts = [slice_vectors(t[s, :c], s % 2, pairs[s // 2], alpha, np) for s, c in enumerate(count)]
    return tuple(np.concatenate(v) for v in zip(*parts))


def _layout_apply(template, alpha: float, count: np.ndarray):
    """The apply function of one slice layout (``count``: the samples read per slice). A batch
    of one measurement (a layout no other file of the job shares: every jittered capture) takes
    the map in factors (:func:`bivariate_values`, float64: no matrix is built); a larger batch
    the layout's matrix (:func:`bivariate_map`, built once, its product in float32). The two
    agree within float32 rounding (tests/test_bivariate.py); which one a file takes depends only
    on the batch's size (on the command line: on its layout's group in the whole job), so a
    rerun or a resumed run gives the same bits."""
    from ._host_build import sample_index

    shape = np.shape(template.t)
    flat = sample_index(np.asarray(template.t), count)
    if len(flat) < 3:
        raise InputError(
            f"the bivariate model needs at least 3 samples; the layout has {len(flat)}"
        )
    pairs = tuple(tuple(float(x) for x in p) for p in template.pairs)
    wi, wv = _directions(template, pairs, alpha, count)
    cos_src = wi[:, 2]
    if not np.all(cos_src > 0):
        raise InputError("the bivariate model needs samples with theta_i below 90 degrees")
    # the residual curves' pairs are the grouping's (slice s of pair s // 2), not inferred again
    pairing = (pairs, np.repeat(np.arange(len(count)) // 2, count))
    cos_dst = _grid()[2]
    # the layout's map, built by its first batch of two or more
    matrix = functools.cache(lambda: bivariate_map(wi, wv, pairs=pairing).astype(np.float32))

    def apply(y):
        y = np.asarray(y, np.float64)
        x = y.reshape(len(y), shape[0] * shape[1], y.shape[-1])[:, flat, :]
        if len(x) == 1:  # a layout of one measurement (a jittered capture): the map in factors
            out = _one(wi, wv, x[0], cos_dst, pairs=pairing)[None]
        else:
            out = _values(matrix(), x, cos_src, cos_dst, LOG_EPS)
        return out.reshape(len(y), 81, 81, y.shape[-1])

    return apply
