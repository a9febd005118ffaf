"""Measured data: flat samples (:class:`Samples`) and samples grouped into slices (:class:`Measurements`).

A grouped measurement is a fixed-shape pytree: slice ``2p`` is the axial slice of elevation pair ``p``
and ``2p + 1`` its diagonal slice; each slice holds up to ``nmax`` samples sorted by angle, padded,
with a count (zero for an unmeasured slice). ``Measurements.mask`` is the one place that says which
entries are samples and which are padding.
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._errors import InputError
from ._slices import KINDS, PROTOCOL_ALPHA_DEG, PROTOCOL_PAIRS, slice_angles


class Samples(eqx.Module):
    """Measured samples in PROTOCOL.md's CSV layout, angles in degrees.

    Attributes:
        theta_i, phi_i, theta_v, phi_v: shape ``(n,)``, degrees.
        rgb: shape ``(n, 3)``, linear RGB ABRDF values (BRDF · cos θi).
    """

    theta_i: Float[Array, " n"]
    phi_i: Float[Array, " n"]
    theta_v: Float[Array, " n"]
    phi_v: Float[Array, " n"]
    rgb: Float[Array, "n 3"]

    def __check_init__(self):
        n = np.shape(self.theta_i)
        for name in ("phi_i", "theta_v", "phi_v"):
            if np.shape(getattr(self, name)) != n:
                raise InputError(
                    f"Samples.{name} has shape {np.shape(getattr(self, name))}, expected {n}"
                )
        if np.shape(self.rgb) != (*n, 3):
            raise InputError(f"Samples.rgb has shape {np.shape(self.rgb)}, expected {(*n, 3)}")

    def __len__(self) -> int:
        return int(np.shape(self.theta_i)[0])

    def to_numpy(self) -> "Samples":
        return Samples(
            *(np.asarray(x) for x in (self.theta_i, self.phi_i, self.theta_v, self.phi_v, self.rgb))
        )

    @staticmethod
    def concatenate(parts: "list[Samples]") -> "Samples":
        return Samples(
            *(
                jnp.concatenate([getattr(p, f) for p in parts])
                for f in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")
            )
        )


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

    @property
    def mask(self):
        """``(..., S, nmax)`` bool: which entries are samples (the rest is padding)."""
        index = jnp.broadcast_to(jnp.arange(self.t.shape[-1], dtype=self.count.dtype), self.t.shape)
        return index < self.count[..., None]

    def replace(self, **fields) -> "Measurements":
        """A copy with some fields replaced (``t``, ``y``, ``count``, ``pairs``, ``has_axial``)."""
        unknown = set(fields) - {"t", "y", "count", "pairs", "has_axial"}
        if unknown:
            raise InputError(f"Measurements has no field(s) {sorted(unknown)}")
        return dataclasses.replace(self, **fields)

    def astype(self, dtype) -> "Measurements":
        """The measurement with ``t`` and ``y`` in ``dtype`` (counts stay integers)."""
        return self.replace(t=jnp.asarray(self.t, dtype), y=jnp.asarray(self.y, dtype))

    def select_slices(self, pair_indices) -> "Measurements":
        """The measurement restricted to some elevation pairs (both slices of each)."""
        rows = np.asarray([r for p in pair_indices for r in (2 * p, 2 * p + 1)])
        return self.replace(
            t=self.t[..., rows, :],
            y=self.y[..., rows, :, :],
            count=self.count[..., rows],
            pairs=tuple(self.pairs[p] for p in pair_indices),
        )

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
    ti, pi_, tv, pv, rgb = (
        np.asarray(x, float) for x in (s.theta_i, s.phi_i, s.theta_v, s.phi_v, s.rgb)
    )

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
        jnp.asarray(t, dtype),
        jnp.asarray(y, dtype),
        jnp.asarray(counts, jnp.int32),
        tuple(tuple(float(x) for x in p) for p in pairs),
        any(c > 0 for c in counts[0::2]),
    )
    report = dict(
        alpha_deg=float(alpha_deg),
        n_used=int(used.sum()),
        n_off_slice=int((~used).sum()),
        counts=counts,
        dropped_pairs=[tuple(float(x) for x in p) for k, p in enumerate(all_pairs) if k in empty],
    )
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
