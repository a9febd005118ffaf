"""Items that fall together, in numpy: the one grouping behind every "average what is equal"
of the package (repeated angles of a slice, the bins of a long slice, the bivariate model's
cells and distinct points, the pair residual's azimuth knots). No JAX: the command line's
readers use it.
"""

from __future__ import annotations

import numpy as np


def key_groups(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(first, which, count)`` of integer keys ``(n,)`` or rows of keys ``(n, d)``: the first
    item of each group (groups in sorted key order), each item's group ``(n,)`` and each group's
    size (float64)."""
    axis = 0 if keys.ndim > 1 else None
    _, first, which = np.unique(keys, axis=axis, return_index=True, return_inverse=True)
    which = which.reshape(-1)
    return first, which, np.bincount(which, minlength=len(first)).astype(np.float64)


def tolerance_groups(x: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`key_groups` of values ``x`` ``(n,)`` or rows ``(n, d)`` equal to ``tol`` (rounded
    to multiples of it)."""
    return key_groups(np.round(x / tol).astype(np.int64))


def cell_means(x: np.ndarray, which: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The mean of the rows of ``x`` ``(n, K)`` in each group: ``(m, K)``."""
    return np.stack([np.bincount(which, c, len(count)) for c in x.T], -1) / count[:, None]
