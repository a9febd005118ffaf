"""The fused model's reconstruction of one sample layout as numpy arrays: applied without JAX.

With fixed hyper-parameters (:mod:`abrdf_jax.prior._fused_settings`) the fused model's posterior
mean (:mod:`abrdf_jax.prior._fused`: prior mean and low-rank covariance, a stationary kernel on
the residual, noise) is linear in the *mapped* samples ``ŷ``:
``m = μ_g + M (ŷ − μ_s)`` with ``M = (σ_p² Q_g Q_sᵀ + σ_k² K_gs) C⁻¹``. With the log-relative map
``ŷ = z − ln(x_ref,s cos θv + ε)``, ``z = ln(max(y, 0) cos θv + ε)``, the table is

``x = max(exp(min(z M' + offset, top)) − ε / cos θv, 0)``,

``M'`` the ``(n_in·w, 6561·w)`` transpose of ``M`` on the valid samples and ``offset`` the grid's
``μ_g + ln((x_ref cos θv + ε) / cos θv) − M (ln(x_ref,s cos θv + ε) + μ_s)``. :class:`FusedEntry`
stores ``[M'; offset]`` as one matrix (a column of ones on ``z`` adds the offset in the product),
so a call is one product of the RBF operator's size plus its element-wise work (one ``log`` on
the way in, one ``exp``, a subtraction and the clamp on the way out). The operator store
(``abrdf_jax._cache``) keeps it beside the RBF's and the prior-only entries. Numpy only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._operator_entry import check_layout
from ._prior_entry import PAIRS, MappedEntry, grid_tables, sample_rows


@dataclasses.dataclass(frozen=True, eq=False)
class FusedEntry(MappedEntry):
    """A built fused-model operator (module docstring), float32 arrays.

    Attributes:
        matrix: ``(n_in·w + 1, 6561·w)``: ``M'`` and, as its last row, the grid offset.
        cos_in: ``(n_in·w,)`` ``cos θv`` at the valid samples.
        floor: ``(6561·w,)`` ``ε / cos θv`` on the grid.
        top: ``(6561·w,)`` the clip before the ``exp`` (the prior's ceiling).
        index, t, count, eps, width: as :class:`~abrdf_jax._prior_entry.PriorEntry`'s.
    """

    matrix: np.ndarray
    cos_in: np.ndarray
    floor: np.ndarray
    top: np.ndarray
    index: np.ndarray
    t: np.ndarray
    count: np.ndarray
    eps: float
    width: int

    KIND = "fused"
    ARRAYS = ("matrix", "cos_in", "floor", "top", "index", "t", "count")

    def apply_compact(self, x) -> np.ndarray:
        """Tables ``(B, 81, 81, 3)`` from the valid samples only, ``(B, n_in, 3)``."""
        rows, b = sample_rows(x, self.width)
        c = np.empty((rows.shape[0], rows.shape[1] + 1), np.float32)
        self.log_samples(rows, out=c[:, :-1])
        c[:, -1] = 1.0
        return grid_tables(c @ self.matrix, self.floor, self.top, b, self.width)

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays and scalars (``None``: nothing)."""
        problem = MappedEntry.check_floats(arrays, meta, ("matrix", "cos_in", "floor", "top"))
        if problem:
            return problem
        w, mat, cos_in, floor = meta["width"], arrays["matrix"], arrays["cos_in"], arrays["floor"]
        if mat.ndim != 2:
            return "malformed (inconsistent array shapes)"
        n_w, d = mat.shape[0] - 1, PAIRS * w
        bad_grid = floor.shape != (d,) or arrays["top"].shape != (d,)
        if mat.shape[1] != d or cos_in.shape != (n_w,) or bad_grid or n_w % w:
            return "malformed (inconsistent array shapes)"
        return check_layout(arrays, n_w // w)
