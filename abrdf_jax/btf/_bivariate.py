"""The chunk map of the bivariate ``(θh, θd)`` model: every texel through one matrix.

``btf reconstruct --model bivariate`` reconstructs each texel as
:func:`abrdf_jax.reconstruct_bivariate` reconstructs one measurement: a thin-plate spline of the
log BRDF in ``(√(θh/90°), θd/90°)`` through every sample at its recorded direction (the
geometry's angles; no slice grouping), evaluated on the UBO grid. The spline's map from the
samples to the grid depends on the geometry only (:func:`abrdf_jax.bivariate_matrix`, float64
numpy, built once), so a chunk is the log of its samples, one matrix product, the exp: the
shape of the RBF operator's chunk, sharded over devices the same way. It is also the isotropic
texels' model of ``--model auto`` (:class:`~abrdf_jax.btf.ModelChoiceChunkFunction`), as it is
``abrdf-jax reconstruct``'s choice for an isotropic file.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._bivariate import LOG_EPS, _grid, bivariate_coordinates, bivariate_matrix
from .._errors import InputError
from .._grid import to_vector
from .._host_eps import EPS_FLOOR
from ._store import ANGLES

N_PAIRS = 81 * 81


class BivariateChunkFunction(eqx.Module):
    """``chunk_fn(y) -> tables``: flat samples ``(C, n, 3)`` to ABRDFs ``(C, 6561, 3)`` by the
    bivariate model (module docstring). Build with :func:`make_bivariate_chunk_fn`."""

    cos_in: Float[Array, " n"]  # cos θi of each flat sample
    matrix: Float[Array, "n 6561"]  # the spline's map (transposed)
    cos_out: Float[Array, " 6561"]  # cos θi of each grid pair (clamped at 0)
    log_eps: float = eqx.field(static=True)

    @property
    def backend(self) -> str:
        return "bivariate"

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        brdf = y.astype(self.matrix.dtype) / self.cos_in[None, :, None]
        # ε per texel and channel, as the library call's (``_host_eps.sample_eps``)
        eps = self.log_eps * jnp.mean(jnp.abs(brdf), axis=1, keepdims=True) + EPS_FLOOR
        z = jnp.log(jnp.maximum(brdf, 0) + eps)
        lin = jnp.einsum("cnk,nq->cqk", z, self.matrix)
        return jnp.maximum((jnp.exp(lin) - eps) * self.cos_out[None, :, None], 0)


def make_bivariate_chunk_fn(geometry: dict, dtype=jnp.float32) -> BivariateChunkFunction:
    """The bivariate chunk map of a measurement store's ``geometry`` (its samples' angles in
    degrees, ``theta_i`` … ``phi_v``), in ``dtype``.

    Raises:
        InputError: a geometry without the four angles, of unequal lengths, with fewer than 3
            samples or ``θi ≥ 90°``, or too few distinct samples for the fit.
    """
    try:
        ti, pi_, tv, pv = (np.deg2rad(np.asarray(geometry[k], np.float64)) for k in ANGLES)
    except KeyError as e:
        raise InputError(f"measurement geometry lacks {e.args[0]!r}") from None
    n = len(ti)
    if n < 3 or any(len(c) != n for c in (pi_, tv, pv)):
        raise InputError(
            "measurement geometry: the bivariate model needs theta_i, phi_i, theta_v, phi_v of "
            f"one length >= 3, got {[len(c) for c in (ti, pi_, tv, pv)]}"
        )
    if np.any(ti >= np.pi / 2):
        raise InputError("measurement geometry: theta_i must be below 90 degrees")
    src = bivariate_coordinates(to_vector(ti, pi_, np), to_vector(tv, pv, np))
    dst, cos_dst = _grid()
    matrix = bivariate_matrix(src, dst)  # (6561, n), float64
    return BivariateChunkFunction(
        cos_in=jnp.asarray(np.cos(ti), dtype),
        matrix=jnp.asarray(matrix.T, dtype),
        cos_out=jnp.asarray(np.maximum(cos_dst, 0.0), dtype),
        log_eps=LOG_EPS,
    )
