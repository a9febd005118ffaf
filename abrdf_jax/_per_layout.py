"""Many grouped measurements, one vectorised pass per slice layout (numpy, no JAX).

A folder's files are usually measured with one angle program: their slices share positions and
counts, so a host computation on their values (the noise estimate of
:mod:`abrdf_jax.select._isotropy`, the smoothing record of :mod:`abrdf_jax._smoothing`) runs
once on the stacked values of each layout and is scattered back. The vectorised pass gives
every measurement the numbers it gets alone (each is a function of its own row: the tests
compare the two).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence

import numpy as np


def layout_of(meas) -> tuple:
    """What measurements must share to be stacked and computed in one pass: the shape of their
    values and the bytes of their slice positions and counts."""
    return np.shape(meas.y), np.asarray(meas.t).tobytes(), np.asarray(meas.count).tobytes()


def stacked_values(measurements: Sequence, ks: Sequence[int]) -> np.ndarray:
    """The values ``y`` of ``measurements[k]`` for ``k`` in ``ks``, stacked: ``(len(ks), ...)``."""
    return np.stack([np.asarray(measurements[k].y) for k in ks])


def per_layout(keys: Sequence[Hashable | None], run: Callable[[list[int]], Sequence]) -> list:
    """``run(ks)`` once for the positions ``ks`` of each distinct key (in the order of their
    first position), its results (one per position of ``ks``) scattered back into a list in the
    order of ``keys``; ``None`` where the key is ``None`` (nothing to compute)."""
    out: list = [None] * len(keys)
    groups: dict = {}
    for k, key in enumerate(keys):
        if key is not None:
            groups.setdefault(key, []).append(k)
    for ks in groups.values():
        for k, r in zip(ks, run(ks)):
            out[k] = r
    return out
