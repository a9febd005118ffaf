"""The chunk map of a learned model (prior only, or fused): every texel through one matrix.

``btf reconstruct --model prior|fused`` reconstructs each texel with a learned prior
(:mod:`abrdf_jax.prior`), as ``abrdf-jax reconstruct --model prior|fused`` does for one file: the
numpy entry of the sample geometry (:func:`abrdf_jax.compile_numpy_operator`: built once in
float64) is the map ``x → max(exp(min(ln(max(x, 0) cos θv + ε) · A + b, top)) − floor, 0)`` on the valid
samples, one row per channel (``shared`` prior) or per texel (``joint``). Here it is collapsed to
that one matrix ``A`` and bias ``b`` (the prior-only entry's two products multiplied out) and run
in JAX, so a chunk is one matrix product, like the RBF operator's, and shards over devices the
same way (:class:`~abrdf_jax.btf._devices.ShardedRunner`).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import InputError

N_PAIRS = 81 * 81


class LearnedChunkFunction(eqx.Module):
    """``chunk_fn(y) -> tables`` of a learned model: flat samples ``(C, n, 3)`` to ABRDFs
    ``(C, 6561, 3)`` (module docstring). Build with :func:`make_learned_chunk_fn`."""

    backend: str = eqx.field(static=True)
    width: int = eqx.field(static=True)
    eps: float = eqx.field(static=True)
    source: Int[Array, " n_in"]  # entry input k is flat sample source[k]
    cos_in: Float[Array, " n_w"]
    matrix: Float[Array, "n_w D"]
    bias: Float[Array, " D"]
    floor: Float[Array, " D"]
    top: Float[Array, " D"]  # the clip before the exp (the prior's ceiling)

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        c = y.shape[0]
        x = y[:, self.source, :].astype(self.matrix.dtype)
        # rows of the map: one per texel and channel (shared) or per texel (joint)
        rows = jnp.swapaxes(x, 1, 2).reshape(c * 3, -1) if self.width == 1 else x.reshape(c, -1)
        z = jnp.log(jnp.maximum(rows, 0) * self.cos_in + self.eps)
        log_out = jnp.minimum(z @ self.matrix + self.bias, self.top)
        out = jnp.maximum(jnp.exp(log_out) - self.floor, 0)
        if self.width == 1:
            return jnp.swapaxes(out.reshape(c, 3, N_PAIRS), 1, 2)
        return out.reshape(c, N_PAIRS, 3)


def make_learned_chunk_fn(
    prior, model: str, template, group, params, budget: str, dtype=jnp.float32
) -> LearnedChunkFunction:
    """The chunk map of learned ``model`` (``"prior"`` or ``"fused"``, at the prior's own
    hyper-parameters) of ``prior`` on the slice layout ``template`` that the grouping matrix
    ``group`` fills from the flat samples (:func:`abrdf_jax.btf._chunkfn.grouping`), α of
    ``params``, reading ``budget``'s slices (``iso102``: the diagonal ones).

    Raises:
        InputError: a geometry whose repeated sample angles are averaged (the map reads each
            input from one flat sample).
    """
    from .._host_operator import compile_numpy_operator

    entry = compile_numpy_operator(prior, template, params, budget=budget, fused=model == "fused")
    rows = np.asarray(group)[np.asarray(entry.index)]
    if not np.all((rows == 0) | (rows == 1)) or not np.all(rows.sum(axis=1) == 1):
        raise InputError(
            f"model={model!r}: repeated sample angles are averaged (not a plain gather); "
            "use model='fixed'"
        )
    if model == "fused":
        mat = np.asarray(entry.matrix, np.float64)
        a, b = mat[:-1], mat[-1]
    else:  # c = z Rᵀ − shift, grid = c Lᵀ + offset: one product
        right, left = np.asarray(entry.right, np.float64), np.asarray(entry.left, np.float64)
        a = right.T @ left.T
        b = np.asarray(entry.offset, np.float64) - left @ np.asarray(entry.shift, np.float64)
    return LearnedChunkFunction(
        backend=model,
        width=int(entry.width),
        eps=float(entry.eps),
        source=jnp.asarray(np.argmax(rows, axis=1), jnp.int32),
        cos_in=jnp.asarray(entry.cos_in, dtype),
        matrix=jnp.asarray(a, dtype),
        bias=jnp.asarray(b, dtype),
        floor=jnp.asarray(entry.floor, dtype),
        top=jnp.asarray(entry.top, dtype),
    )


def prior_identity(prior) -> dict:
    """What a BTF job's results depend on of the prior: its digest and the fused model's
    hyper-parameters (the output store's job record; a store of another prior is not resumed)."""
    from .._prior_operator import _in_memory

    src = _in_memory(prior)
    return {"sha256": src.sha256, "fused": src.fused_settings()}
