"""Grouping a real capture into slices: pairs, slice offset, tolerance, true positions, density.

:func:`group_slices` takes any flat list of samples (a protocol capture, a continuous video of
thousands of samples, jittered angles, a device's own elevations, extra pairs, gaps) to the
fixed-shape :class:`~abrdf_jax.Measurements` of the pipeline, and says what it did in a report.
Each step is linear in the sample values (samples are placed, copied where slices cross and
averaged), so the BTF path reads the same grouping off as one matrix
(:mod:`abrdf_jax.btf._chunkfn`).

1. **Elevation pairs** (:func:`infer_pairs`): the elevations of the samples fall into levels
   (gaps over ``PAIR_GAP_DEG`` separate them); a level's elevation is its median, snapped to a
   UBO ring within ``RING_SNAP_DEG`` (so its RBF centres stay grid pairs); every (θi, θv)
   combination of levels that holds samples is a pair. Given ``pairs``, a sample belongs to a
   pair within ``PAIR_GAP_DEG`` of both elevations.
2. **Slice offset** α (:func:`estimate_alpha`): the mode of ``φi ∓ φv`` over all samples, refined
   as the median of the offsets near it; its uncertainty is the standard error of that median.
3. **Tolerance**: a sample is on a slice when its across-slice offset (``φi − φv − α`` for the
   axial, ``φi + φv − α`` for the diagonal slice, mod 360°) is within ``tol_deg``; by default
   ``max(0.5°, 4 σ)`` capped at ``MAX_TOL_DEG``, with ``σ`` the robust spread of the offsets (an
   exact capture keeps today's 0.5°; 0.5° encoder jitter gives about 2.8°). Samples outside are
   counted and reported, never silently left out.
4. **True positions**: an on-slice sample enters at the orthogonal projection of its ``(φi, φv)``
   onto the slice (its along-slice coordinate, not snapped to any grid); only its across-slice
   offset (at most ``tol_deg``) and its elevation's deviation from the pair are neglected by
   the slice models; each slot also keeps its samples' recorded directions
   (``SliceArrays.directions``), which the bivariate model reads.
5. **Density**: a slice with more than ``max_knots`` samples (default 360) is reduced to the
   means (position and value) of ``max_knots`` equal bins of its parameter (1° of φ, 2° of
   ``φi ∓ φv``): the RBF centres read a slice every 7.5°, so nothing they can use is lost, the
   peak is kept to within a bin, and the averages lower the noise by the square root of the
   samples per bin. Repeated angles are averaged in any case.
6. **Centres**: the RBF centres of a pair are the (φi, φv) of its rings' UBO azimuths (12 on the
   30° ring), which sample the slices every 15° of φi ∓ φv. When every diagonal slice has at least
   ``DENSE_KNOTS`` knots (one per 7.5° of its parameter), the slices resolve more: the centres take
   ``DENSE_AZIMUTHS`` azimuths per ring (``Measurements.centre_azimuths``); the grid pairs among
   them are still put back as restored. A sparse capture keeps the UBO layout, where more centres
   only interpolate the same samples and measured worse (docs/captures.md).
7. **Gaps**: a stretch of a slice wider than ``GAP_FACTOR`` times its median spacing (and
   ``MIN_GAP_DEG``) is a gap; the slice interpolation bridges it and the report lists it.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ._arrays import SampleColumns, SliceArrays
from ._errors import InputError
from ._groups import cell_means, key_groups, tolerance_groups
from ._grid import mean_directions, to_vector
from ._memo import BoundedMemo
from ._protocol import PROTOCOL_PAIRS, UBO_THETAS_DEG

if TYPE_CHECKING:  # JAX pytrees: built from the numpy result only by group_slices
    from ._measurements import Measurements, Samples

#: Elevation levels further apart than this are different pairs (degrees).
PAIR_GAP_DEG = 2.5
#: A level within this of a UBO ring takes the ring's elevation (degrees).
RING_SNAP_DEG = 1.0
#: A level off the rings is rounded to this step (degrees), so one device's captures share their
#: pairs under encoder error (a folder, one RBF map: ``abrdf_jax._engine``); at most 0.125° off.
LEVEL_STEP_DEG = 0.25
#: Fewest samples that make an elevation pair (fewer: reported as stray, left out).
MIN_PAIR_SAMPLES = 3
#: Widest automatic slice tolerance (degrees).
MAX_TOL_DEG = 5.0
#: A slice longer than this is reduced to bin means.
MAX_KNOTS = 360
#: Knots on every diagonal slice that make a capture dense, and its centre azimuths per ring.
DENSE_KNOTS, DENSE_AZIMUTHS = 48, 24
#: A gap: wider than this many median spacings and than MIN_GAP_DEG.
GAP_FACTOR, MIN_GAP_DEG = 2.5, 5.0


def _wrap(x):
    """Angles (degrees) to (−180, 180]."""
    return (np.asarray(x, float) + 180.0) % 360.0 - 180.0


def _levels(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elevation levels of ``theta`` (degrees) and the level of every sample."""
    order = np.argsort(theta)
    cut = np.nonzero(np.diff(theta[order]) > PAIR_GAP_DEG)[0] + 1
    label = np.empty(len(theta), int)
    centres = []
    for k, idx in enumerate(np.split(order, cut)):
        label[idx] = k
        c = float(np.median(theta[idx]))
        ring = min(UBO_THETAS_DEG, key=lambda r: abs(r - c))
        snap = abs(ring - c) <= RING_SNAP_DEG
        centres.append(float(ring) if snap else round(c / LEVEL_STEP_DEG) * LEVEL_STEP_DEG)
    return np.asarray(centres), label


def infer_pairs(theta_i, theta_v) -> tuple[tuple[tuple[float, float], ...], np.ndarray]:
    """The elevation pairs of a capture and the pair of every sample (``-1``: stray sample).

    Args:
        theta_i, theta_v: elevations of the samples (degrees).

    Returns:
        ``(pairs, index)``: pairs ``(θi, θv)`` sorted ascending (PROTOCOL.md's order for its
        pairs), and per sample the index of its pair, ``-1`` for a sample of a combination with
        fewer than ``MIN_PAIR_SAMPLES`` samples.
    """
    ti, tv = np.asarray(theta_i, float), np.asarray(theta_v, float)
    ci, li = _levels(ti)
    cv, lv = _levels(tv)
    nv = len(cv)
    code = li * nv + lv  # the (level i, level v) combination of every sample
    codes, counts = np.unique(code, return_counts=True)
    keep = [divmod(int(c), nv) for c, n in zip(codes, counts) if n >= MIN_PAIR_SAMPLES]
    keep.sort(key=lambda c: (ci[c[0]], cv[c[1]]))
    pairs = tuple((float(ci[a]), float(cv[b])) for a, b in keep)
    lookup = np.full(len(ci) * nv, -1)
    for k, (a, b) in enumerate(keep):
        lookup[a * nv + b] = k
    return pairs, lookup[code]


def _pair_index(ti, tv, pairs) -> np.ndarray:
    """The given pair nearest to every sample within ``PAIR_GAP_DEG`` (``-1``: none)."""
    p = np.asarray(pairs, float).reshape(-1, 2)
    dist = np.maximum(np.abs(ti[:, None] - p[None, :, 0]), np.abs(tv[:, None] - p[None, :, 1]))
    best = np.argmin(dist, axis=1)
    return np.where(dist[np.arange(len(ti)), best] <= PAIR_GAP_DEG, best, -1)


def _offsets(pi_, pv, alpha_deg):
    """Across-slice offsets (degrees) of every sample: axial ``φi − φv − α``, diagonal ``φi + φv − α``."""
    return _wrap(pi_ - pv - alpha_deg), _wrap(pi_ + pv - alpha_deg)


def _near_offsets(pi_, pv, alpha_deg, window):
    ax, dg = _offsets(pi_, pv, alpha_deg)
    both = np.concatenate([ax, dg])
    return both[np.abs(both) <= window]


def estimate_alpha(samples: "Samples") -> float:
    """Estimate the slice offset α (degrees) from measured samples.

    Every on-slice sample has either ``φi − φv ≡ α`` (axial) or ``φi + φv ≡ α`` (diagonal),
    modulo 360°. The estimate is the most frequent of those values (1° bins, smoothed over three
    bins so that jittered angles still vote together), refined as the median of the values within
    ``MAX_TOL_DEG`` of it and then within the tolerance their spread gives.
    """
    return estimate_alpha_spread(samples)[0]


def estimate_alpha_spread(samples: "Samples") -> tuple[float, float, float]:
    """``(α, standard error of α, robust σ of the across-slice offsets)``, degrees."""
    s = samples.to_numpy()
    return _alpha_spread(np.asarray(s.phi_i, float), np.asarray(s.phi_v, float))


def _alpha_spread(pi_, pv) -> tuple[float, float, float]:
    cand = np.concatenate([(pi_ - pv) % 360.0, (pi_ + pv) % 360.0])
    hist = np.bincount(np.round(cand).astype(int) % 360, minlength=360)
    smooth = hist + 0.5 * (np.roll(hist, 1) + np.roll(hist, -1))
    # exact protocol angles fall on one bin: prefer it; jittered ones spread over neighbours
    alpha = float(np.argmax(smooth + 1e-3 * hist))
    window = MAX_TOL_DEG
    for _ in range(3):
        near = _near_offsets(pi_, pv, alpha, window)
        if near.size == 0:
            break
        alpha = float((alpha + np.median(near)) % 360.0)
        sigma = _spread(_near_offsets(pi_, pv, alpha, window))
        window = _tolerance(sigma)
    near = _near_offsets(pi_, pv, alpha, window)
    sigma = _spread(near)
    se = 1.2533 * sigma / np.sqrt(max(near.size, 1))
    alpha = round(alpha, 6) % 360.0
    if 360.0 - alpha < 1e-4:  # an offset of 0 read through float32 angles: not "360 deg"
        alpha = 0.0
    return alpha, float(se), float(sigma)


def _spread(offsets) -> float:
    """Robust σ (1.4826 · MAD) of across-slice offsets."""
    if len(offsets) < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(offsets - np.median(offsets))))


def _tolerance(sigma: float) -> float:
    return float(min(max(0.5, 4.0 * sigma), MAX_TOL_DEG))


def _reduce(angle, src, max_knots):
    """Sort a slice, average repeated angles and, past ``max_knots`` samples, bin means:
    ``(knot angles, samples in sorted order, the knot of each, samples per knot)``."""
    order = np.argsort(angle, kind="stable")
    angle, src = angle[order], src[order]
    if len(angle) == 0:
        return angle, src, np.zeros(0, np.int64), np.zeros(0)
    if len(angle) > max_knots:
        keys = np.minimum((angle / 360.0 * max_knots).astype(np.int64), max_knots - 1)
        _, inv, cnt = key_groups(keys)
    else:
        _, inv, cnt = tolerance_groups(angle, 1e-6)
    return cell_means(angle[:, None], inv, cnt)[:, 0], src, inv, cnt


def _gaps(angle_deg) -> list[tuple[float, float]]:
    """Stretches ``(from, to)`` (degrees) of a periodic slice with no sample (see the docstring)."""
    n = len(angle_deg)
    if n < 3:
        return []
    step = np.diff(np.concatenate([angle_deg, [angle_deg[0] + 360.0]]))
    big = np.nonzero(step > max(GAP_FACTOR * np.median(step), MIN_GAP_DEG))[0]
    return [(float(angle_deg[k]), float((angle_deg[k] + step[k]) % 360.0)) for k in big]


def group_slices(
    samples: "Samples",
    alpha_deg: float | None = None,
    pairs=None,
    tol_deg: float | None = None,
    nmax: int | None = None,
    dtype=np.float32,
    min_axial: int = 3,
    max_knots: int = MAX_KNOTS,
    centre_azimuths: int | None | str = "auto",
) -> tuple["Measurements", dict]:
    """Group arbitrary measured samples into slices (steps 1–6 of the module docstring).

    :func:`group_arrays` (numpy, no JAX), its slices as a :class:`~abrdf_jax.Measurements`;
    the arguments, report and errors are that function's.
    """
    arrays, report = group_arrays(
        samples, alpha_deg, pairs, tol_deg, nmax, dtype, min_axial, max_knots, centre_azimuths
    )
    return arrays.to_measurements(), report


def group_arrays(
    samples,
    alpha_deg: float | None = None,
    pairs=None,
    tol_deg: float | None = None,
    nmax: int | None = None,
    dtype=np.float32,
    min_axial: int = 3,
    max_knots: int = MAX_KNOTS,
    centre_azimuths: int | None | str = "auto",
) -> tuple[SliceArrays, dict]:
    """Group arbitrary measured samples into slices (steps 1–6 of the module docstring), numpy.

    Args:
        samples: the measured samples (degrees): :class:`~abrdf_jax.Samples` or the columns of
            :func:`abrdf_jax.io.read_sample_columns`.
        alpha_deg: the slice offset; ``None`` estimates it with :func:`estimate_alpha`.
        pairs: elevation pairs to group on; ``None`` infers them from the data
            (:func:`infer_pairs`). Given pairs without any sample are left out.
        tol_deg: across-slice tolerance (degrees); ``None``: from the spread of the offsets.
        nmax: padded slice length; default: the next multiple of 8 above the longest slice.
        min_axial: an axial slice with fewer samples of its own counts as not measured.
        max_knots: longest slice kept as it is; longer ones become bin means.
        centre_azimuths: RBF centre azimuths per ring (``None``: the UBO rings'); ``"auto"``:
            ``DENSE_AZIMUTHS`` for a dense capture (step 6), else ``None``.

    Returns:
        ``(slices, report)``: the slices (``SliceArrays``, the fields of
        :class:`~abrdf_jax.Measurements` as numpy arrays of ``dtype``); ``report`` has ``alpha_deg``, ``alpha_se_deg``, ``tol_deg``,
        ``offset_sigma_deg``, ``n_used``, ``n_off_slice`` (all samples left out), ``n_stray`` (those at no pair),
        ``n_raw`` (on-slice samples per slice before reduction), ``counts`` (knots per slice),
        ``gaps`` and ``dropped_pairs`` (expected pairs without samples: the given ones, or the
        protocol's or the elevation levels' combinations).

    Raises:
        InputError: when no sample lies on any diagonal slice.
    """
    _check_arguments(samples, alpha_deg, pairs, tol_deg, max_knots, centre_azimuths)
    s = samples.to_numpy()
    angles = tuple(np.asarray(x, float) for x in (s.theta_i, s.phi_i, s.theta_v, s.phi_v))
    pairs = None if pairs is None else tuple(tuple(float(x) for x in p) for p in pairs)
    layout = _cached_layout(
        angles, alpha_deg, pairs, tol_deg, nmax, min_axial, max_knots, centre_azimuths
    )
    meas = SliceArrays(
        np.asarray(layout.t, dtype),
        np.asarray(layout.values(np.asarray(s.rgb, float)), dtype),
        np.asarray(layout.report["counts"], np.int32),
        layout.pairs,
        layout.has_axial,
        layout.centre_azimuths,
        np.asarray(layout.directions, dtype),
    )
    report = {k: list(v) if isinstance(v, list) else v for k, v in layout.report.items()}
    return meas, report


def grouping_matrix(angles, alpha_deg: float | None, pairs=None, dtype=np.float32):
    """The grouping of samples at ``angles`` (``theta_i, phi_i, theta_v, phi_v``, degrees) as a
    matrix: ``(slices, G)`` with ``slices`` the :func:`group_arrays` result of zero values and
    ``G`` ``(S · nmax, n)``, ``y_slices = G @ y_flat`` (the grouping is linear in the values)."""
    angles = tuple(np.asarray(a, float) for a in angles)
    n = len(angles[0])
    slices, _ = group_arrays(
        SampleColumns(*angles, np.zeros((n, 3))), alpha_deg, pairs, dtype=dtype
    )
    pairs = None if pairs is None else tuple(tuple(float(x) for x in p) for p in pairs)
    layout = _cached_layout(angles, alpha_deg, pairs, None, None, 3, MAX_KNOTS, "auto")
    g = np.zeros((layout.per_slot.shape[0], n), dtype)
    g[layout.dst, layout.src] = 1.0 / layout.per_slot[layout.dst]
    return slices, g


def _cached_layout(angles, *args) -> "_Layout":
    return _LAYOUTS.get((_digest(angles), *args), lambda: _layout(angles, *args))


#: Slice layouts by the digest of their angles and the grouping's arguments: a folder of
#: captures made with one angle program (a device's nominal angles, or simulated ones) groups
#: its angles once; only the values are placed per file. Oldest out past 64.
_LAYOUTS = BoundedMemo(64)


def _digest(angles) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    for a in angles:
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.digest()


class _Layout(NamedTuple):
    """Where every sample goes: the slices' parameters and report (from the angles alone) and
    the linear map of the values, ``y[dst] = mean of rgb[src]`` over each slot's samples."""

    t: np.ndarray
    pairs: tuple
    has_axial: bool
    centre_azimuths: int | None
    report: dict
    dst: np.ndarray
    src: np.ndarray
    per_slot: np.ndarray  # samples averaged into each slot (0: padding)
    directions: np.ndarray  # (S, nmax, 2, 3) each slot's recorded (wi, wv) (_slot_directions)

    def values(self, rgb: np.ndarray) -> np.ndarray:
        """``(S, nmax, 3)`` slice values (float64) of the samples' ``rgb``."""
        size = self.per_slot.shape[0]
        total = np.stack([np.bincount(self.dst, rgb[self.src, c], size) for c in range(3)], 1)
        out = np.divide(
            total,
            self.per_slot[:, None],
            out=np.zeros_like(total),
            where=self.per_slot[:, None] > 0,
        )
        return out.reshape(*self.t.shape, 3)


def _layout(angles, alpha_deg, pairs, tol_deg, nmax, min_axial, max_knots, centre_azimuths):
    """The :class:`_Layout` of a capture's angles (steps 1–7 of the module docstring)."""
    ti, pi_, tv, pv = angles
    if alpha_deg is None:
        alpha_deg, alpha_se, sigma = _alpha_spread(pi_, pv)
    else:  # given: only the spread of the offsets around it is measured
        sigma = _spread(_near_offsets(pi_, pv, alpha_deg, MAX_TOL_DEG))
        alpha_se = 0.0
    tol = _tolerance(sigma) if tol_deg is None else float(tol_deg)
    if pairs is None:
        pairs, index = infer_pairs(ti, tv)
        expected = _expected_pairs(pairs)
    else:
        index, expected = _pair_index(ti, tv, pairs), pairs
    off_ax, off_dg = _offsets(pi_, pv, alpha_deg)
    groups, raw = [], []
    used = np.zeros(len(ti), bool)
    for k in range(len(pairs)):
        on_pair = index == k
        ax = on_pair & (np.abs(off_ax) <= tol)
        dg = on_pair & (np.abs(off_dg) <= tol)
        # Samples at the two crossings lie on both slices and serve both. An axial slice made
        # of crossing samples alone was not measured.
        if np.count_nonzero(ax & ~dg) < min_axial:
            ax = np.zeros_like(ax)
        # true positions: the orthogonal projection onto the slice (see the module docstring)
        groups.append(((pi_[ax] - off_ax[ax] / 2) % 360.0, np.nonzero(ax)[0]))
        groups.append(((pv[dg] - off_dg[dg] / 2) % 360.0, np.nonzero(dg)[0]))
        raw += [int(ax.sum()), int(dg.sum())]
        used |= ax | dg
    merged = [_reduce(a, idx, max_knots) for a, idx in groups]
    counts = [len(m[0]) for m in merged]
    if sum(counts[1::2]) == 0:
        raise InputError(
            f"no sample lies on a diagonal slice (phi_i + phi_v = alpha = {alpha_deg:g} deg mod 360, "
            f"within {tol:g} deg, at elevation pairs {pairs}); cannot reconstruct"
        )
    # A pair without a single sample would feed zeros into the RBF at a quarter of its centres
    # (silently dark); it is left out instead, and the RBF fills it from the other pairs
    # (docs/stability.md, "Numerical edges").
    keep = [k for k in range(len(pairs)) if counts[2 * k] + counts[2 * k + 1] > 0]
    pairs = tuple(pairs[k] for k in keep)
    merged = [merged[r] for k in keep for r in (2 * k, 2 * k + 1)]
    raw = [raw[r] for k in keep for r in (2 * k, 2 * k + 1)]
    counts = [len(m[0]) for m in merged]
    nmax = nmax or int(8 * np.ceil(max(counts) / 8))
    t = np.zeros((len(merged), nmax))
    per_slot = np.zeros(len(merged) * nmax)
    dst, src, gaps = [], [], []
    for k, (a, idx, inv, cnt) in enumerate(merged):
        t[k, : len(a)] = np.deg2rad(a)
        per_slot[k * nmax : k * nmax + len(a)] = cnt
        dst.append(k * nmax + inv)
        src.append(idx)
        kind = ("axial", "diagonal")[k % 2]
        gaps += [
            dict(pair=pairs[k // 2], slice=kind, start_deg=g0, end_deg=g1) for g0, g1 in _gaps(a)
        ]
    if centre_azimuths == "auto":
        dense = min(counts[1::2]) >= DENSE_KNOTS
        centre_azimuths = DENSE_AZIMUTHS if dense else None
    report = dict(
        alpha_deg=float(alpha_deg),
        alpha_se_deg=float(alpha_se),
        tol_deg=tol,
        offset_sigma_deg=float(sigma),
        n_used=int(used.sum()),
        n_off_slice=int((~used).sum()),
        n_stray=int((index < 0).sum()),
        n_raw=raw,
        counts=counts,
        gaps=gaps,
        dropped_pairs=[p for p in expected if p not in pairs],
    )
    has_axial = any(c > 0 for c in counts[0::2])
    dst, src = np.concatenate(dst), np.concatenate(src)
    directions = _slot_directions(angles, dst, src, t.shape)
    return _Layout(t, pairs, has_axial, centre_azimuths, report, dst, src, per_slot, directions)


def _slot_directions(angles, dst, src, shape) -> np.ndarray:
    """``(S, nmax, 2, 3)``: the recorded ``(wi, wv)`` of each slot's samples (their normalised
    mean where a slot averages several; zeros: padding)."""
    ti, pi_, tv, pv = (np.deg2rad(a)[src] for a in angles)
    size = shape[0] * shape[1]
    w = [mean_directions(to_vector(a, b, np), dst, size) for a, b in ((ti, pi_), (tv, pv))]
    return np.stack(w, 1).reshape(*shape, 2, 3)


_SAMPLE_FIELDS = ("theta_i", "phi_i", "theta_v", "phi_v", "rgb", "to_numpy")


def _check_arguments(samples, alpha_deg, pairs, tol_deg, max_knots, centre_azimuths) -> None:
    """An InputError naming the argument of :func:`group_slices` that cannot be used."""
    if not all(hasattr(samples, f) for f in _SAMPLE_FIELDS):
        raise InputError(f"group_slices: samples must be Samples, got {type(samples).__name__}")
    if len(samples) == 0:
        raise InputError("group_slices: no samples")
    if alpha_deg is not None and not np.isfinite(alpha_deg):
        raise InputError(f"group_slices: alpha_deg must be a finite angle, got {alpha_deg!r}")
    if pairs is not None and (len(pairs) == 0 or any(len(p) != 2 for p in pairs)):
        raise InputError(f"group_slices: pairs must be (theta_i, theta_v) pairs, got {pairs!r}")
    if tol_deg is not None and not (np.isfinite(tol_deg) and 0 < tol_deg <= 45):
        raise InputError(f"group_slices: tol_deg must lie in (0, 45] degrees, got {tol_deg!r}")
    if not (isinstance(max_knots, (int, np.integer)) and max_knots >= 8):
        raise InputError(f"group_slices: max_knots must be an int >= 8, got {max_knots!r}")
    ok = centre_azimuths in (None, "auto") or (
        isinstance(centre_azimuths, (int, np.integer)) and 1 <= centre_azimuths <= 72
    )
    if not ok:
        raise InputError(
            f"group_slices: centre_azimuths must be None, 'auto' or an int in [1, 72], got "
            f"{centre_azimuths!r}"
        )


def _expected_pairs(found) -> tuple:
    """Pairs a capture was meant to hold: with any protocol pair among those found, the found ones
    and the protocol's; else the found ones and, when they fill most of it, the grid of their
    elevation levels (a device's own 2 x 2 elevations with one pair missing)."""
    if set(found) & set(PROTOCOL_PAIRS):
        return tuple(sorted(set(found) | set(PROTOCOL_PAIRS)))
    lv_i = sorted({a for a, _ in found})
    lv_v = sorted({b for _, b in found})
    grid = [(a, b) for a in lv_i for b in lv_v]
    return tuple(grid) if len(grid) <= len(found) + 1 else tuple(found)


def layout_key(meas: Measurements) -> str:
    """A digest (sha256, hex) of a measurement's slice layout (pairs, axial slices, centre layout,
    the valid slice positions as float32, counts): two measurements with equal keys share one
    compiled operator (in a run, :mod:`abrdf_jax._engine`, and in the operator store, whose key
    holds it, :func:`abrdf_jax._cache.operator_key`). Accepts anything with the slice arrays of
    a :class:`~abrdf_jax.Measurements` (numpy or JAX)."""
    count = np.asarray(meas.count)
    t = np.asarray(meas.t)
    valid = np.arange(t.shape[-1])[None, :] < count[:, None]
    h = hashlib.sha256()
    h.update(repr((meas.pairs, meas.has_axial, meas.centre_azimuths, t.shape)).encode())
    h.update(count.astype(np.int64).tobytes())
    h.update(np.where(valid, t, 0.0).astype(np.float32).tobytes())
    return h.hexdigest()
