"""A simulated slice-capturing device: what a real, continuous capture records.

The paper's device turns the sample under a fixed light and camera (the axial slice) and moves
light and camera in opposite directions (the diagonal slice), recording continuously. A real
capture therefore differs from PROTOCOL.md's ideal one in the ways :func:`simulate_capture`
models, one argument each:

- ``per_slice``: any number of samples per slice, from a handful to thousands (a video);
- ``jitter_deg``: the device does not sit exactly on the nominal slice: each of the four angles
  of a sample deviates by a normal error of this σ (degrees); the value is taken at the true,
  deviated directions and the angles recorded are those true angles (read off accurate
  encoders), so a reconstruction can use them as they are;
- ``noise``: relative value noise, ``y · (1 + noise · N(0, 1))`` per channel;
- ``pairs`` and ``alpha_deg``: the device's own elevations and slice offset;
- ``gap_deg``: the camera occludes the light near the retro direction: samples whose light and
  view directions are less than this angle apart are missing (a gap in the slices of the pairs
  with equal elevations).

It is the forward model of ``python -m benchmarks.captures`` and of the tests of real captures.
"""

from __future__ import annotations

import numpy as np

from ._errors import InputError
from ._grid import to_vector
from ._measurements import Samples
from ._slices import KINDS, PROTOCOL_ALPHA_DEG, PROTOCOL_COUNTS, PROTOCOL_PAIRS, slice_angles


def _per_slice_counts(per_slice, pairs) -> list[int]:
    if per_slice is None:
        same = tuple(map(tuple, pairs)) == PROTOCOL_PAIRS
        return list(PROTOCOL_COUNTS) if same else [24] * len(pairs)
    counts = [per_slice] * len(pairs) if np.ndim(per_slice) == 0 else list(per_slice)
    if len(counts) != len(pairs):
        raise InputError(f"per_slice has {len(counts)} counts for {len(pairs)} elevation pairs")
    for c in counts:
        if int(c) != c or c < 1:
            raise InputError(f"per_slice must be positive integers, got {per_slice!r}")
    return [int(c) for c in counts]


def simulate_capture(
    model,
    *,
    pairs=PROTOCOL_PAIRS,
    alpha_deg: float = PROTOCOL_ALPHA_DEG,
    per_slice=None,
    budget: str = "aniso204",
    jitter_deg: float = 0.0,
    noise: float = 0.0,
    gap_deg: float = 0.0,
    seed: int = 0,
) -> Samples:
    """The samples a continuous slice capture of ``model`` records (see the module docstring).

    Args:
        model: a callable ``model(wi, wv) -> (..., 3)`` of unit vectors (a material).
        pairs: elevation pairs ``(θi, θv)`` in degrees (any elevations in [0, 90)).
        alpha_deg: slice offset α.
        per_slice: samples per slice: ``None`` for PROTOCOL.md's counts at its pairs (24 per
            slice elsewhere), an int for every slice, or one count per pair.
        budget: ``"aniso204"`` (axial and diagonal slices) or ``"iso102"`` (diagonal only).
        jitter_deg: σ of the normal deviation of every angle from the nominal slice (degrees).
        noise: relative σ of the value noise.
        gap_deg: samples whose light and view directions are closer than this are missing.
        seed: of the jitter and the noise.

    Returns:
        :class:`Samples` (numpy, degrees): the true angles of every sample and its value.
    """
    if budget not in ("aniso204", "iso102"):
        raise InputError(f"budget must be 'aniso204' or 'iso102', got {budget!r}")
    for name, v in (("jitter_deg", jitter_deg), ("noise", noise), ("gap_deg", gap_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be a finite number >= 0, got {v!r}")
    pairs = [tuple(float(x) for x in p) for p in pairs]
    if any(not (0 <= t < 90) for p in pairs for t in p):
        raise InputError(f"elevations must lie in [0, 90) degrees, got pairs {pairs}")
    counts = _per_slice_counts(per_slice, pairs)
    rng = np.random.default_rng(seed)
    alpha = np.deg2rad(alpha_deg)
    cols = []
    for (ti, tv), n in zip(pairs, counts):
        t = np.arange(n) * 2 * np.pi / n
        for kind in KINDS[budget == "iso102" :]:
            pi_, pv = (np.rad2deg(np.asarray(a, float)) for a in slice_angles(kind, t, alpha))
            cols.append(np.stack([np.full(n, ti), pi_, np.full(n, tv), pv], axis=1))
    ang = np.concatenate(cols)
    if jitter_deg:
        ang = ang + rng.normal(0.0, jitter_deg, ang.shape)
        ang[:, [0, 2]] = np.clip(ang[:, [0, 2]], 0.0, 89.5)
        ang[:, [1, 3]] %= 360.0
    rad = np.deg2rad(ang)
    wi, wv = to_vector(rad[:, 0], rad[:, 1]), to_vector(rad[:, 2], rad[:, 3])
    wi, wv = np.asarray(wi, np.float32), np.asarray(wv, np.float32)
    if gap_deg:
        apart = np.rad2deg(np.arccos(np.clip(np.sum(wi * wv, axis=1), -1.0, 1.0)))
        keep = apart >= gap_deg
        ang, wi, wv = ang[keep], wi[keep], wv[keep]
    rgb = np.asarray(model(wi, wv), np.float64)
    if noise:
        rgb = rgb * (1.0 + noise * rng.normal(size=rgb.shape))
    return Samples(*(ang[:, j] for j in range(4)), rgb)
