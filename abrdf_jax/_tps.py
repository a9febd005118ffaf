"""A thin-plate spline in 2-D with a degree-1 polynomial and a ridge on the kernel's diagonal,
as linear maps of the values at its points (numpy, float64): what the bivariate model
(:mod:`abrdf_jax._bivariate`) fits in the plane of ``(θh, θd)``.

``s(x) = Σ_j c_j φ(|x − x_j|) + a₀ + a·x`` with ``φ(r) = r² ln r`` (Duchon 1977), the
coefficients from the symmetric system ``[[K + λI, P], [Pᵀ, 0]] [c; a] = [y; 0]``. Above
:data:`MAX_POINTS` points the plane is binned first (the solve is ``O(n³)``): the centres are
the means of the occupied cells and the values there the means of theirs. The fit is a
:class:`Fit`: its coefficients either as a map of the values (:meth:`Fit.coef`, the system's
inverse: what a layout's matrix needs) or of given values (:meth:`Fit.coef_of`, one solve:
what one measurement needs).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._errors import InputError
from ._groups import cell_means, key_groups
from ._kernels import kernel_block

#: Above this many samples the plane is binned before the solve, which costs ``O(n³)``: cells
#: of 1/:data:`BINS` per axis, coarser (halved) until at most this many are occupied.
MAX_POINTS = 2048
BINS = 128


def kernel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The thin-plate kernel ``r² ln r`` between the points ``a`` ``(m, 2)`` and ``b`` ``(n, 2)``
    (the RBF's own, :func:`abrdf_jax._kernels.kernel_block`, at unit widths)."""
    return kernel_block(a, b, 1.0, "thin_plate_spline", np)


def poly(x: np.ndarray) -> np.ndarray:
    return np.concatenate([np.ones((len(x), 1)), x], axis=1)


def binned(src: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(centres, which, count)``: cell centres ``(m, 2)`` (the mean of their points), each
    point's cell ``(n,)`` and each cell's number of points ``(m,)``, ``m ≤ MAX_POINTS``."""
    bins = BINS
    while True:
        cell = np.clip((src * bins).astype(np.int64), 0, bins - 1)
        _, which, count = key_groups(cell[:, 0] * bins + cell[:, 1])
        if len(count) <= MAX_POINTS or bins == 1:
            break
        bins //= 2
    return cell_means(src, which, count), which, count


class Fit(NamedTuple):
    """A thin-plate fit at the points ``src`` ``(n, 2)``: its centres ``(m, 2)``, the system
    ``(m + 3, m + 3)`` of kernel, ridge and degree-1 polynomial, and the binning (``which``,
    ``count``; ``None`` when the centres are the points themselves)."""

    centres: np.ndarray
    system: np.ndarray
    which: np.ndarray | None
    count: np.ndarray | None

    def _solve(self, rhs: np.ndarray) -> np.ndarray:
        """The coefficients ``(m + 3, K)`` of values ``rhs`` ``(m, K)`` at the centres."""
        full = np.zeros((len(self.system), rhs.shape[1]))
        full[: len(rhs)] = rhs
        try:
            return np.linalg.solve(self.system, full)
        except np.linalg.LinAlgError as e:  # fewer than 3 distinct points in a line, say
            raise InputError(
                f"the bivariate fit is singular ({e}): too few distinct samples"
            ) from e

    def coef(self) -> np.ndarray:
        """The coefficients as a map ``(m + 3, n)`` of the values at the points (the maps are
        GEMMs with the system's inverse)."""
        inv = self._solve(np.eye(len(self.centres)))
        if self.which is None:
            return inv
        return inv[:, self.which] / self.count[self.which][None, :]

    def coef_of(self, z: np.ndarray) -> np.ndarray:
        """The coefficients ``(m + 3, K)`` of values ``z`` ``(n, K)`` at the points: one solve
        with ``K`` right-hand sides, no inverse."""
        return self._solve(z if self.which is None else cell_means(z, self.which, self.count))


def fit(src: np.ndarray, smoothing: float) -> Fit:
    """The spline's fit at the points ``src`` ``(n, 2)`` (binned past :data:`MAX_POINTS`)."""
    src = np.asarray(src, np.float64)
    centres, which, count = binned(src) if len(src) > MAX_POINTS else (src, None, None)
    n = len(centres)
    system = np.zeros((n + 3, n + 3))
    system[:n, :n] = kernel(centres, centres) + smoothing * np.eye(n)
    system[:n, n:] = poly(centres)
    system[n:, :n] = poly(centres).T
    return Fit(centres, system, which, count)


def basis(x: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``(len(x), m + 3)``: the kernel at the centres and the degree-1 polynomial at ``x``."""
    x = np.asarray(x, np.float64)
    return np.concatenate([kernel(x, centres), poly(x)], axis=1)


#: Rows of the basis evaluated at once by :func:`basis_times` (its memory: this many rows
#: of ``m + 3`` float64 values, ``m ≤`` :data:`MAX_POINTS`: about 34 MB).
ROWS = 2048


def basis_times(x: np.ndarray, centres: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """``basis(x, centres) @ coef`` ``(len(x), K)``, :data:`ROWS` rows at a time."""
    parts = [basis(x[k : k + ROWS], centres) @ coef for k in range(0, len(x), ROWS)]
    return np.concatenate(parts) if parts else np.zeros((0, coef.shape[1]))
