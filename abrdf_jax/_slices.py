"""Slice geometry (eq. 1) and grouping of measured samples into slices.

At an elevation pair ``(θi, θv)`` two slices are measured (Filip 2012, eq. 1):

- axial ``s_A(φi) = B(θi, θv, φi, φv = φi − α)``: the sample rotates under fixed light and camera;
- diagonal ``s_D(φv) = B(θi, θv, φi = 2π − φv + α, φv)``: light and camera move in opposite
  directions.

The axial slice is parameterized by ``φi``, the diagonal slice by ``φv``. PROTOCOL.md fixes the
protocol positions: ``φ = k · 2π / N`` with ``N = 25, 25, 26, 26`` for the pairs
``30/30, 30/75, 75/30, 75/75``.

A grouped measurement is a :class:`Measurements` pytree of fixed shape: slice ``2p`` is the axial
slice of pair ``p`` and ``2p + 1`` its diagonal slice; each slice holds up to ``nmax`` samples
sorted by angle, padded, with a count (zero for an unmeasured slice).
"""

from __future__ import annotations

import equinox as eqx

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._errors import InputError
from ._samples import Samples

PROTOCOL_PAIRS = ((30.0, 30.0), (30.0, 75.0), (75.0, 30.0), (75.0, 75.0))
PROTOCOL_COUNTS = (25, 25, 26, 26)
PROTOCOL_ALPHA_DEG = 15.0
KINDS = ("axial", "diagonal")


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


class Measurements(eqx.Module):
    """Samples grouped into slices, as a fixed-shape pytree.

    Attributes:
        t: ``(S, nmax)`` slice parameter (radians, sorted, in [0, 2π)), padding past ``count``.
        y: ``(S, nmax, 3)`` linear RGB values (padding is zero).
        count: ``(S,)`` number of valid samples per slice (0: slice not measured).
        pairs: static tuple of the ``P = S / 2`` elevation pairs ``(θi, θv)`` in degrees.
        has_axial: static; whether any axial slice was measured (decides the budget).
    """

    t: Float[Array, "S nmax"]
    y: Float[Array, "S nmax 3"]
    count: Int[Array, " S"]
    pairs: tuple = eqx.field(static=True)
    has_axial: bool = eqx.field(static=True)

    @property
    def n_samples(self) -> int:
        return int(np.sum(np.asarray(self.count)))

    def to_samples(self, alpha_deg: float = PROTOCOL_ALPHA_DEG) -> Samples:
        """Flatten to a :class:`Samples` list (numpy), e.g. to write a measurement CSV."""
        t = np.asarray(self.t)
        y = np.asarray(self.y)
        cnt = np.asarray(self.count)
        alpha = np.deg2rad(alpha_deg)
        cols = [[], [], [], [], []]
        for s in range(t.shape[0]):
            k = int(cnt[s])
            if k == 0:
                continue
            ti, tv = self.pairs[s // 2]
            pi_, pv = slice_angles(KINDS[s % 2], t[s, :k], alpha)
            cols[0].append(np.full(k, ti))
            cols[1].append(np.rad2deg(np.asarray(pi_)))
            cols[2].append(np.full(k, tv))
            cols[3].append(np.rad2deg(np.asarray(pv)))
            cols[4].append(y[s, :k])
        return Samples(*(np.concatenate(c) for c in cols))


def protocol_counts(budget: str) -> tuple[int, ...]:
    """Per-slice sample counts (axial, diagonal per pair) of a PROTOCOL budget."""
    if budget == "iso102":
        return tuple(c for n in PROTOCOL_COUNTS for c in (0, n))
    if budget == "aniso204":
        return tuple(c for n in PROTOCOL_COUNTS for c in (n, n))
    raise ValueError(f"budget must be 'iso102' or 'aniso204', got {budget!r}")


def protocol_parameters(counts: tuple[int, ...], nmax: int | None = None, dtype=jnp.float32):
    """Slice parameters ``t[s, k] = k · 2π / N_s`` (padded) and the counts as arrays."""
    nmax = nmax or max(max(counts), 1)
    t = np.zeros((len(counts), nmax))
    for s, n in enumerate(counts):
        if n:
            t[s, :n] = np.arange(n) * 2 * np.pi / n
    return jnp.asarray(t, dtype), jnp.asarray(counts, jnp.int32)


def slice_directions(t, pairs, alpha):
    """Unit vectors ``(wi, wv)`` of every slice position, shapes ``(S, nmax, 3)``.

    Differentiable in ``alpha`` (radians) and ``t``.
    """
    from ._grid import to_vector

    wi, wv = [], []
    for s in range(t.shape[0]):
        ti, tv = pairs[s // 2]
        pi_, pv = slice_angles(KINDS[s % 2], t[s], alpha)
        wi.append(to_vector(jnp.full_like(pi_, np.deg2rad(ti)), pi_))
        wv.append(to_vector(jnp.full_like(pv, np.deg2rad(tv)), pv))
    return jnp.stack(wi), jnp.stack(wv)


def sample_model(model, counts, alpha, pairs=PROTOCOL_PAIRS, dtype=jnp.float32) -> Measurements:
    """Sample the PROTOCOL slices from a continuous model ``model(wi, wv) -> (..., 3)``.

    Args:
        model: callable of unit vectors (illumination, view), returning ABRDF values.
        counts: per-slice counts (see :func:`protocol_counts`); 0 leaves a slice unmeasured.
        alpha: slice offset in radians (traced: the samples are differentiable in α).
        pairs: elevation pairs in degrees.
    """
    t, count = protocol_parameters(counts, dtype=dtype)
    wi, wv = slice_directions(t, pairs, jnp.asarray(alpha, dtype))
    y = model(wi, wv)
    valid = (jnp.arange(t.shape[1])[None, :] < count[:, None])[..., None]
    y = jnp.where(valid, y, 0.0).astype(dtype)
    return Measurements(t, y, count, tuple(pairs), any(c > 0 for c in counts[0::2]))


def sample_table(table, counts, alpha, pairs=PROTOCOL_PAIRS, dtype=jnp.float32) -> Measurements:
    """Sample the PROTOCOL slices from a dense 81×81 UBO table, interpolating over azimuth.

    Both azimuths are interpolated periodically and linearly on their rings (bilinear over
    ``(φi, φv)``), so the result is differentiable in α. The elevations must be UBO rings.
    """
    from ._grid import ring_indices, ubo_grid

    table = jnp.asarray(table, dtype)
    if table.shape != (81, 81, 3):
        raise InputError(f"table must have shape (81, 81, 3), got {table.shape}")
    _, phi_deg = ubo_grid()
    t, count = protocol_parameters(counts, dtype=dtype)
    alpha = jnp.asarray(alpha, dtype)
    ys = []
    for s in range(t.shape[0]):
        ti, tv = pairs[s // 2]
        ri, rv = ring_indices(ti), ring_indices(tv)
        pi_, pv = slice_angles(KINDS[s % 2], t[s], alpha)
        ii0, ii1, wi_ = _ring_weights(pi_, len(ri))
        vv0, vv1, wv_ = _ring_weights(pv, len(rv))
        sub = table[np.ix_(ri, rv)]  # (ni, nv, 3)
        v00, v01 = sub[ii0, vv0], sub[ii0, vv1]
        v10, v11 = sub[ii1, vv0], sub[ii1, vv1]
        a, b = wi_[:, None], wv_[:, None]
        ys.append((1 - a) * ((1 - b) * v00 + b * v01) + a * ((1 - b) * v10 + b * v11))
    y = jnp.stack(ys)
    valid = (jnp.arange(t.shape[1])[None, :] < count[:, None])[..., None]
    y = jnp.where(valid, y, 0.0)
    return Measurements(t, y, count, tuple(pairs), any(c > 0 for c in counts[0::2]))


def _ring_weights(phi, n):
    x = jnp.mod(phi, 2 * jnp.pi) * n / (2 * jnp.pi)
    k0 = jnp.floor(x)
    w = x - k0
    k0 = k0.astype(jnp.int32) % n
    return k0, (k0 + 1) % n, w


def estimate_alpha(samples: Samples) -> float:
    """Estimate the slice offset α (degrees) from measured samples.

    Every on-slice sample has either ``φi − φv ≡ α`` (axial) or ``φi + φv ≡ α`` (diagonal),
    modulo 360°. The estimate is the most frequent of those values (0.5° bins), refined as the
    median of the values in the winning bin.
    """
    pi_ = np.asarray(samples.phi_i, float)
    pv = np.asarray(samples.phi_v, float)
    cand = np.concatenate([(pi_ - pv) % 360.0, (pi_ + pv) % 360.0])
    bins = np.round(cand * 2).astype(int) % 720
    best = np.bincount(bins, minlength=720).argmax()
    near = cand[np.abs(((cand - best / 2 + 180) % 360) - 180) <= 0.5]
    return float(np.median(near))


def group_slices(
    samples: Samples,
    alpha_deg: float | None = PROTOCOL_ALPHA_DEG,
    pairs=PROTOCOL_PAIRS,
    tol_deg: float = 0.5,
    nmax: int | None = None,
    dtype=np.float32,
    min_axial: int = 3,
) -> tuple[Measurements, dict]:
    """Group arbitrary measured samples into the slices of ``pairs``.

    A sample belongs to the slice of pair ``(θi, θv)`` when both elevations match within
    ``tol_deg`` and its azimuths satisfy ``φi − φv ≡ α`` (axial) or ``φi + φv ≡ α`` (diagonal)
    within ``tol_deg`` (mod 360°). Other samples are off-slice: they are tolerated, counted and
    left out. Repeated angles within a slice are averaged (a duplicated sample would otherwise
    make the interpolation ill-defined). A sample where the slices cross belongs to both; an
    axial slice with fewer than ``min_axial`` samples of its own counts as not measured.

    Args:
        samples: the measured samples (degrees).
        alpha_deg: the slice offset; ``None`` estimates it with :func:`estimate_alpha`.
        nmax: padded slice length; default: the next multiple of 8 above the longest slice.

    Returns:
        ``(measurements, report)`` where ``report`` has ``alpha_deg``, ``n_used``,
        ``n_off_slice``, ``counts`` and ``dropped_pairs``: elevation pairs without any sample,
        left out of the measurement (its ``pairs`` are the others).

    Raises:
        InputError: when no sample lies on any diagonal slice.
    """
    s = samples.to_numpy()
    if alpha_deg is None:
        alpha_deg = estimate_alpha(s)
    ti, pi_, tv, pv, rgb = (np.asarray(x, float) for x in (s.theta_i, s.phi_i, s.theta_v, s.phi_v, s.rgb))

    def close(a, b):
        d = (a - b + 180.0) % 360.0 - 180.0
        return np.abs(d) <= tol_deg

    groups = []
    all_pairs = list(pairs)
    used = np.zeros(len(ti), bool)
    for a_t, v_t in pairs:
        on_pair = (np.abs(ti - a_t) <= tol_deg) & (np.abs(tv - v_t) <= tol_deg)
        ax = on_pair & close(pi_ - pv, alpha_deg)
        dg = on_pair & close(pi_ + pv, alpha_deg)
        # Samples at the two crossings (φi, φv) = (α, 0), (α + π, π) lie on both slices and
        # serve both. An axial slice made of crossing samples alone was not measured.
        if np.count_nonzero(ax & ~dg) < min_axial:
            ax = np.zeros_like(ax)
        groups.append((pi_[ax] % 360.0, rgb[ax]))
        groups.append((pv[dg] % 360.0, rgb[dg]))
        used |= ax | dg
    merged = [_merge_duplicates(a, v) for a, v in groups]
    counts = [len(a) for a, _ in merged]
    if sum(counts[1::2]) == 0:
        raise InputError(
            f"no sample lies on a diagonal slice (phi_i + phi_v = alpha = {alpha_deg:g} deg mod 360 "
            f"at elevation pairs {pairs}); cannot reconstruct"
        )
    # An elevation pair without a single sample would feed zeros into the RBF at a quarter of its
    # centres (silently dark); it is left out instead, and the RBF fills it from the other pairs
    # (docs/stability.md, "Numerical edges").
    empty = [k for k in range(len(pairs)) if counts[2 * k] + counts[2 * k + 1] == 0]
    if empty:
        pairs = [p for k, p in enumerate(pairs) if k not in empty]
        merged = [m for k, m in enumerate(merged) if k // 2 not in empty]
        counts = [len(a) for a, _ in merged]
    nmax = nmax or int(8 * np.ceil(max(counts) / 8))
    t = np.zeros((len(merged), nmax))
    y = np.zeros((len(merged), nmax, 3))
    for k, (a, v) in enumerate(merged):
        t[k, : len(a)] = np.deg2rad(a)
        y[k, : len(a)] = v
    meas = Measurements(
        jnp.asarray(t, dtype), jnp.asarray(y, dtype), jnp.asarray(counts, jnp.int32),
        tuple(tuple(float(x) for x in p) for p in pairs), any(c > 0 for c in counts[0::2]),
    )
    report = dict(alpha_deg=float(alpha_deg), n_used=int(used.sum()), n_off_slice=int((~used).sum()),
                  counts=counts, dropped_pairs=[tuple(float(x) for x in p) for k, p in enumerate(all_pairs) if k in empty])
    return meas, report


def _merge_duplicates(angle, values, tol=1e-6):
    order = np.argsort(angle, kind="stable")
    angle, values = angle[order], values[order]
    if len(angle) == 0:
        return angle, values
    keys = np.round(angle / tol).astype(np.int64)
    uniq, inv = np.unique(keys, return_inverse=True)
    out_a = np.zeros(len(uniq))
    out_v = np.zeros((len(uniq), values.shape[1]))
    cnt = np.zeros(len(uniq))
    np.add.at(out_a, inv, angle)
    np.add.at(out_v, inv, values)
    np.add.at(cnt, inv, 1)
    return out_a / cnt, out_v / cnt[:, None]


def stack_measurements(items: list[Measurements]) -> Measurements:
    """Stack measurements of one layout along a new leading (material) axis, padding slices."""
    if not items:
        raise ValueError("no measurements to stack")
    pairs = items[0].pairs
    for m in items:
        if m.pairs != pairs:
            raise InputError("cannot stack measurements of different elevation pairs")
    nmax = max(m.t.shape[1] for m in items)

    def pad(x, axis_len):
        w = [(0, 0)] * x.ndim
        w[1] = (0, axis_len - x.shape[1])
        return jnp.pad(x, w)

    return Measurements(
        jnp.stack([pad(m.t, nmax) for m in items]),
        jnp.stack([pad(m.y, nmax) for m in items]),
        jnp.stack([m.count for m in items]),
        pairs,
        any(m.has_axial for m in items),
    )


