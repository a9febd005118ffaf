"""The prior-only reconstruction of one sample layout as numpy arrays: applied without JAX.

For a fixed layout (slice positions, counts, α, the slices used) the prior-only model of
:mod:`abrdf_jax.prior` (Nielsen et al. 2015; docs/prior.md) is linear in the *mapped* samples:

1. map: ``z = ln(max(y, 0) cos θv + ε) − ln(x_ref,s cos θv + ε)`` (the log-relative map);
2. matrix: ``m = μ + Q R (z − μ_s)`` with ``R = (Q_sᵀ Q_s + λI)⁻¹ Q_sᵀ`` (:func:`ridge_operator`
   on the valid samples) and ``Q`` the components on the grid;
3. inverse map: ``x = max((exp(m) (x_ref cos θv + ε) − ε) / cos θv, 0)``
   ``= max(exp(m + ln((x_ref cos θv + ε) / cos θv)) − ε / cos θv, 0)``.

:class:`PriorEntry` stores that map with the constants folded in (``R`` and ``Q`` as two
factors: ``K`` is small, so ``(rows · Rᵀ) · Qᵀ`` costs less than the product matrix would; the
grid offset rides in the second product as one more column), so that its element-wise work is
the RBF operator's: one ``exp``, one subtraction, the clamp;
the operator store (``abrdf_jax._cache``) keeps it beside the RBF's :class:`OperatorEntry`.
This module imports numpy only.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ._errors import InputError
from ._operator_entry import GRID, check_layout

PAIRS = GRID[0] * GRID[1]


def sample_rows(x, width: int) -> tuple[np.ndarray, int]:
    """``(rows, B)``: valid samples ``(B, n_in, 3)`` as the rows a prior's map reads: one per
    material and channel (``width`` 1, the shared layout) or one per material in (sample,
    channel) order (``width`` 3, joint)."""
    x = np.asarray(x, np.float32)
    b = x.shape[0]
    if width == 1:
        return np.ascontiguousarray(np.transpose(x, (0, 2, 1))).reshape(b * 3, -1), b
    return x.reshape(b, -1), b


def grid_tables(m: np.ndarray, floor: np.ndarray, top: np.ndarray, b: int, width: int):
    """The inverse map of mapped grid rows ``m`` (clipped at ``top``, ``exp``, minus ``floor``,
    clamped at 0; in place) as tables ``(B, 81, 81, 3)``."""
    np.minimum(m, top, out=m)
    np.exp(m, out=m)
    m -= floor
    np.maximum(m, np.float32(0.0), out=m)
    if width == 1:
        return np.ascontiguousarray(np.transpose(m.reshape(b, 3, PAIRS), (0, 2, 1))).reshape(
            b, *GRID, 3
        )
    return m.reshape(b, *GRID, 3)


class MappedEntry:
    """What the prior's entries share: the layout (``index``, ``t``, ``count``), the sample
    values' check, and the stored form (``ARRAYS``, ``eps``, ``width``)."""

    ARRAYS: tuple[str, ...] = ()

    @property
    def n_inputs(self) -> int:
        return int(self.index.shape[0])

    def apply(self, y) -> np.ndarray:
        """Tables ``(..., 81, 81, C)`` from stacked sample values ``(..., S, nmax, C)``."""
        y = np.asarray(y, np.float32)
        s, nmax = self.t.shape
        if y.ndim < 3 or y.shape[-3:-1] != (s, nmax) or y.shape[-1] != 3:
            raise InputError(f"values must have shape (..., {s}, {nmax}, 3), got {y.shape}")
        lead = y.shape[:-3]
        x = y.reshape(-1, s * nmax, 3)[:, self.index, :]
        return self.apply_compact(x).reshape(*lead, *GRID, 3)

    def arrays(self) -> dict[str, np.ndarray]:
        return {n: getattr(self, n) for n in self.ARRAYS}

    def meta(self) -> dict:
        return {"eps": float(self.eps), "width": int(self.width)}

    @classmethod
    def from_stored(cls, arrays: dict[str, np.ndarray], meta: dict):
        return cls(**arrays, eps=meta["eps"], width=meta["width"])

    def log_samples(self, rows, out=None) -> np.ndarray:
        """``ln(max(y, 0) cos θv + ε)`` of sample rows ``(R, n_in·w)`` (the map's log), into
        ``out`` if given."""
        out = np.maximum(rows, np.float32(0.0), out=out)
        out *= self.cos_in
        out += np.float32(self.eps)
        return np.log(out, out=out)

    @staticmethod
    def check_floats(arrays: dict[str, np.ndarray], meta: dict, floats) -> str | None:
        """The map's scalars and the float32 arrays ``floats`` (``None``: fine)."""
        w, eps = meta.get("width"), meta.get("eps")
        if w not in (1, 3) or not isinstance(eps, float) or not eps > 0:
            return "malformed (no prior map)"
        if not all(arrays[n].dtype == np.float32 for n in floats):
            return "malformed (inconsistent array shapes)"
        return None


@dataclasses.dataclass(frozen=True, eq=False)
class PriorEntry(MappedEntry):
    """A built prior-only operator (module docstring), float32 arrays.

    Attributes:
        right: ``(K, n_in·w)`` the ridge map ``R`` on the mapped valid samples.
        shift: ``(K,)`` ``R · (ln(x_ref,s cos θv + ε) + μ_s)``: the map's reference and the
            mean at the samples, folded in.
        left: ``(6561·w, K)`` the components ``Q`` on the grid.
        offset: ``(6561·w,)`` ``μ + ln((x_ref cos θv + ε) / cos θv)`` on the grid.
        cos_in: ``(n_in·w,)`` ``cos θv`` at the valid samples.
        floor: ``(6561·w,)`` ``ε / cos θv`` on the grid.
        top: ``(6561·w,)`` the clip before the ``exp`` (the prior's ceiling,
            :func:`abrdf_jax._prior_operator.entry_layout`).
        index, t, count: the template's layout as :class:`OperatorEntry`'s (``count`` of the
            template; ``index`` only the samples the model reads).
        eps: ε of the prior's map; width: ``w``, 1 (``shared`` channels: one row per channel) or
            3 (``joint``: one row per material, pair-major).
    """

    right: np.ndarray
    shift: np.ndarray
    left: np.ndarray
    offset: np.ndarray
    cos_in: np.ndarray
    floor: np.ndarray
    top: np.ndarray
    index: np.ndarray
    t: np.ndarray
    count: np.ndarray
    eps: float
    width: int

    KIND = "prior"
    ARRAYS = ("right", "shift", "left", "offset", "cos_in", "floor", "top", "index", "t", "count")

    @functools.cached_property
    def _grid_map(self) -> np.ndarray:
        """``[Q | offset]ᵀ`` ``(K + 1, 6561·w)``: the second product adds the offset."""
        return np.ascontiguousarray(np.concatenate([self.left, self.offset[:, None]], 1).T)

    def apply_compact(self, x) -> np.ndarray:
        """The same from the valid samples only, ``(B, n_in, 3)`` → ``(B, 81, 81, 3)``."""
        rows, b = sample_rows(x, self.width)
        z = self.log_samples(rows)
        c = np.empty((rows.shape[0], self.shift.shape[0] + 1), np.float32)
        np.matmul(z, self.right.T, out=c[:, :-1])
        c[:, :-1] -= self.shift
        c[:, -1] = 1.0
        return grid_tables(c @ self._grid_map, self.floor, self.top, b, self.width)

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays and scalars (``None``: nothing)."""
        floats = ("right", "shift", "left", "offset", "cos_in", "floor", "top")
        problem = MappedEntry.check_floats(arrays, meta, floats)
        if problem:
            return problem
        w, r, left = meta["width"], arrays["right"], arrays["left"]
        if r.ndim != 2:
            return "malformed (inconsistent array shapes)"
        k, n_w = r.shape
        d = PAIRS * w
        shapes = {"shift": (k,), "left": (d, k), "offset": (d,), "cos_in": (n_w,)}
        if any(arrays[n].shape != s for n, s in shapes.items()) or any(
            arrays[n].shape != (d,) for n in ("floor", "top")
        ):
            return "malformed (inconsistent array shapes)"
        if n_w % w or left.size == 0:
            return "malformed (inconsistent array shapes)"
        return check_layout(arrays, n_w // w)
