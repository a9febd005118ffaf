"""The chunk map of the bivariate ``(θh, θd)`` model: every texel through one matrix.

``btf reconstruct --model bivariate`` reconstructs each texel as
:func:`abrdf_jax.reconstruct_bivariate` reconstructs one measurement: a thin-plate spline of the
log BRDF in ``(√(θh/90°), θd/90°)`` through every sample at its recorded direction (the
geometry's angles; no slice grouping), with the measured pairs' residual curves, evaluated on
the UBO grid. The model's map from the samples to the grid depends on the geometry only
(:func:`abrdf_jax._bivariate.bivariate_map`, float64 numpy, built once), so a chunk is the log of its samples, one matrix product, the exp: the
shape of the RBF operator's chunk, sharded over devices the same way. It is also the isotropic
texels' model of ``--model auto`` (:class:`~abrdf_jax.btf.ModelChoiceChunkFunction`), as it is
``abrdf-jax reconstruct``'s choice for an isotropic file.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._bivariate import (
    LOG_EPS,
    _grid,
    bivariate_map,
    checked_angles,
    from_log,
    log_brdf,
    source_vectors,
)
from .._errors import InputError
from ._store import ANGLES

N_PAIRS = 81 * 81


class BivariateChunkFunction(eqx.Module):
    """``chunk_fn(y) -> tables``: flat samples ``(C, n, 3)`` to ABRDFs ``(C, 6561, 3)`` by the
    bivariate model (module docstring). Build with :func:`make_bivariate_chunk_fn`."""

    cos_in: Float[Array, " n"]  # cos θi of each flat sample
    matrix: Float[Array, "n 6561"]  # the spline's map (transposed)
    cos_out: Float[Array, " 6561"]  # cos θi of each grid pair
    log_eps: float = eqx.field(static=True)

    @property
    def backend(self) -> str:
        return "bivariate"

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        z, eps = log_brdf(y.astype(self.matrix.dtype), self.cos_in, self.log_eps, jnp)
        return from_log(jnp.einsum("cnk,nq->cqk", z, self.matrix), eps, self.cos_out, jnp)


def make_bivariate_chunk_fn(geometry: dict, dtype=jnp.float32) -> BivariateChunkFunction:
    """The bivariate chunk map of a measurement store's ``geometry`` (its samples' angles in
    degrees, ``theta_i`` … ``phi_v``), in ``dtype``.

    Raises:
        InputError: a geometry without the four angles, or angles that
            :func:`abrdf_jax._bivariate.checked_angles` refuses, or too few distinct samples
            for the fit.
    """
    missing = [k for k in ANGLES if k not in geometry]
    if missing:
        raise InputError(f"measurement geometry lacks {missing[0]!r}")
    ti, pi_, tv, pv = checked_angles(geometry.__getitem__, "measurement geometry")
    matrix = bivariate_map(*source_vectors(ti, pi_, tv, pv))  # (6561, n), float64
    cos_dst = _grid()[2]
    return BivariateChunkFunction(
        cos_in=jnp.asarray(np.cos(ti), dtype),
        matrix=jnp.asarray(matrix.T, dtype),
        cos_out=jnp.asarray(cos_dst, dtype),
        log_eps=LOG_EPS,
    )
