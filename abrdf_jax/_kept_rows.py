"""The spike cap's kept rows of the compiled operator, as a sparse product.

Where the restored subspaces go back (``ReconstructionOperator.keep``: the grid pairs of the RBF
centres) the operator's output is ``M[keep] · z`` of the *uncapped* features (``_spikes.py``).
Those rows of ``M`` are the restoration itself: each reads the few samples around its pair
(``(op.matrix[op.keep] != 0).sum(1)``: 2 to 4 of 102 for the recommended iso102 setting, 8 of
210 in the BTF chunk map of ``btf.measurement_geometry()``), so their product is a sum of a few
gathered columns, not a second dense product (``python -m benchmarks.btf``, ``python -m
benchmarks``: the recommended operator's throughput).
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int


#: The kept rows' product runs as a sparse sum when each kept row of the matrix has at most this
#: fraction of its columns nonzero (with linear slice interpolation a restored value reads a few
#: samples: module docstring), else as a dense product.
SPARSE_KEPT = 0.25


def kept_columns(matrix, keep) -> np.ndarray | None:
    """``(k, nnz)`` column indices of the nonzeros of the kept rows ``matrix[keep]`` (each row's
    nonzeros, then columns where the row is zero: their weights are 0), or ``None`` (no kept
    rows, a traced matrix, or rows too dense for :data:`SPARSE_KEPT`: the dense product)."""
    if isinstance(matrix, jax.core.Tracer) or len(keep) == 0:
        return None
    rows = np.asarray(matrix)[np.asarray(keep)] != 0
    nnz = max(int(rows.sum(axis=1).max()), 1)
    if nnz > SPARSE_KEPT * rows.shape[1]:
        return None
    # a stable sort puts each row's nonzero columns first, in order, then its zero ones
    return np.argsort(~rows, axis=1, kind="stable")[:, :nnz].astype(np.int32)


def kept_weights(op):
    """What the kept rows' product of operator ``op`` reads, taken once per call: ``M[keep]``
    ``(k, f)``, or its nonzero weights ``(k, nnz)`` at ``op.keep_columns``."""
    kept = op.matrix[op.keep]
    if op.keep_columns is None:
        return kept
    return jnp.take_along_axis(kept, op.keep_columns, axis=1)


def kept_product(
    weights: Float[Array, "k nnz"], cols: Int[Array, "k nnz"], rows: Float[Array, "BC f"]
) -> Float[Array, "BC k"]:
    """``rows · M[keep]ᵀ`` ``(B·C, k)`` from the kept rows' nonzero ``weights`` at columns
    ``cols`` (:func:`kept_weights`, ``op.keep_columns``): a sum of ``nnz`` gathered columns, one
    fused loop (the dense product of the kept rows does ``f / nnz`` times the flops)."""
    acc = weights[None, :, 0] * rows[:, cols[:, 0]]
    for j in range(1, cols.shape[1]):
        acc = acc + weights[None, :, j] * rows[:, cols[:, j]]
    return acc
