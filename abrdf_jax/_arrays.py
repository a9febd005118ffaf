"""Measured data as plain numpy arrays (no JAX): what the command line plans with.

:class:`SampleColumns` is a measurement file's columns (:func:`abrdf_jax.io.read_sample_columns`),
:class:`SliceArrays` the samples grouped into slices (:func:`abrdf_jax._grouping.group_arrays`).
They hold the same fields as :class:`abrdf_jax.Samples` and :class:`abrdf_jax.Measurements`,
which are JAX pytrees; ``to_samples()``/``to_measurements()`` make those of them (importing JAX)
only where the numerics need it, so that a warm command-line call never does (issue 13).
"""

from __future__ import annotations

from typing import NamedTuple

from ._errors import InputError, non_finite

import numpy as np


class SampleColumns(NamedTuple):
    """Flat measured samples, angles in degrees (the fields of :class:`abrdf_jax.Samples`)."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_v: np.ndarray
    phi_v: np.ndarray
    rgb: np.ndarray

    def __len__(self) -> int:  # the number of samples, as Samples (not the number of fields)
        return int(np.shape(self.theta_i)[0])

    def to_numpy(self) -> "SampleColumns":
        return self

    def to_samples(self):
        """The :class:`abrdf_jax.Samples` of these columns (imports JAX)."""
        from ._measurements import Samples

        return Samples(*self)


def slice_rows(pair_indices) -> np.ndarray:
    """Rows (axial ``2p``, diagonal ``2p + 1``) of the elevation pairs ``pair_indices``."""
    return np.asarray([r for p in pair_indices for r in (2 * p, 2 * p + 1)], np.int64)


class SliceArrays(NamedTuple):
    """Samples grouped into slices, numpy (the fields of :class:`abrdf_jax.Measurements`).

    Attributes:
        t: ``(S, nmax)`` slice parameters (radians), y: ``(S, nmax, 3)`` values, count: ``(S,)``
        valid samples per slice; pairs, has_axial, centre_azimuths as in ``Measurements``;
        directions: ``(S, nmax, 2, 3)`` the recorded unit vectors ``(wi, wv)`` of each slot's
        samples (their normalised mean where a slot averages several; ``None``: not known),
        which the slice positions ``t`` only project (a model that reads directions, as the
        bivariate one, uses them; :class:`~abrdf_jax.Measurements` does not hold them).
    """

    t: np.ndarray
    y: np.ndarray
    count: np.ndarray
    pairs: tuple
    has_axial: bool
    centre_azimuths: int | None = None
    directions: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(np.sum(self.count))

    @property
    def mask(self) -> np.ndarray:
        """``(S, nmax)`` bool: which entries are samples (the rest is padding)."""
        return np.arange(self.t.shape[-1])[None, :] < self.count[:, None]

    def select_slices(self, pair_indices) -> "SliceArrays":
        """Restricted to some elevation pairs (both slices of each)."""
        rows = slice_rows(pair_indices)
        pairs = tuple(self.pairs[p] for p in pair_indices)
        d = None if self.directions is None else self.directions[rows]
        return self._replace(
            t=self.t[rows], y=self.y[rows], count=self.count[rows], pairs=pairs, directions=d
        )

    def to_measurements(self):
        """The :class:`abrdf_jax.Measurements` of these slices (imports JAX; same dtypes)."""
        import jax.numpy as jnp

        from ._measurements import Measurements
        from ._xp import to_device

        return Measurements(
            to_device(self.t),
            to_device(self.y),
            jnp.asarray(self.count, jnp.int32),
            self.pairs,
            self.has_axial,
            self.centre_azimuths,
        )


def check_finite(table, where: str = "reconstruction") -> None:
    """Raise :class:`InputError` if ``table`` holds NaN or inf (never write such a table).

    Args:
        table: a reconstructed table (any shape, last axis RGB).
        where: what to name in the message (the input file).
    """
    arr = np.asarray(table)
    found = non_finite(arr)
    if found is not None:
        count, first = found
        raise InputError(
            f"{where}: the reconstruction holds {count} NaN or infinite value(s) (first at "
            f"index {first}): the sample values are too large for {arr.dtype} arithmetic or the RBF solve failed; "
            "nothing was written for it (rescale the values, e.g. to a maximum near 1)"
        )
