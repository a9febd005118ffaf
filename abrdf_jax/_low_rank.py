"""The compiled operator's matrix as two thin factors where its rank is below its width.

The operator's matrix ``M`` ``(q, f)`` is ``K · A``: the RBF evaluation at the ``q`` targets
times the map from the ``f`` samples to the RBF's coefficients, through the restored subspaces
(``_operator.py``). Its rank is therefore at most what those share, and often below ``f``: 84 of
102 columns for the recommended iso102 setting, 156 of 210 for the BTF chunk map of
``btf.measurement_geometry()`` (the factors' ranks ``python -m benchmarks`` and ``python -m
benchmarks.btf`` print). Then ``M = U · W`` with ``U`` ``(q, r)``
and ``W`` ``(r, f)``, and a batch's product ``rows · Mᵀ`` is ``(rows · Wᵀ) · Uᵀ``:
``r · (q + f)`` multiply-adds per row instead of ``q · f`` (0.77 of them for the BTF chunk map,
0.84 for iso102), the same result to rounding.

Only a float64 matrix is factored: in a float32 build the rounding noise of the build (~1e-7
of the largest singular value) hides where the rank ends.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: Singular values at or below this fraction of the largest are taken as the float64 build's
#: rounding (float64's ε is 2.2e-16): the factors reproduce the matrix to that fraction.
RANK_RTOL = 1e-11

#: Factor only when the two products do at most this fraction of the dense product's work.
MAX_WORK = 0.9

#: Factor only matrices of at most this many columns (samples): the SVD costs ``~4 q f²``
#: flops, a few GFLOP for the BTF chunk map's ``(6561, 210)`` and hundreds for the thousands
#: of samples of a dense capture's operator, which then keeps the dense product.
MAX_COLUMNS = 512


def low_rank_factors(matrix) -> tuple[np.ndarray, np.ndarray] | None:
    """``(U, W)`` with ``U · W = matrix`` to float64 rounding, ``U`` ``(q, r)``, ``W`` ``(r, f)``
    (the singular values split evenly between them), or ``None``: a traced or non-float64
    matrix, one wider than :data:`MAX_COLUMNS`, or a rank too close to the width to save
    :data:`MAX_WORK` of the work."""
    if isinstance(matrix, jax.core.Tracer):
        return None
    m = np.asarray(matrix)
    if m.dtype != np.float64 or m.ndim != 2 or 0 in m.shape or m.shape[1] > MAX_COLUMNS:
        return None
    if not np.isfinite(m).all():
        return None
    q, f = m.shape
    u, s, vt = np.linalg.svd(m, full_matrices=False)
    if not s[0] > 0:
        return None
    r = int(np.count_nonzero(s > RANK_RTOL * s[0]))
    if r * (q + f) > MAX_WORK * q * f:
        return None
    root = np.sqrt(s[:r])
    return u[:, :r] * root, root[:, None] * vt[:r]


def product(
    matrix: Float[Array, "q f"], rows: Float[Array, "n f"], factors=None
) -> Float[Array, "n q"]:
    """``rows · matrixᵀ``, through ``factors`` ``(U, W)`` (:func:`low_rank_factors`) where
    given: ``(rows · Wᵀ) · Uᵀ``."""
    if factors is not None:
        u, w = factors
        return product(u, product(w, rows))
    return jnp.matmul(rows, matrix.T, precision=jax.lax.Precision.HIGHEST)
