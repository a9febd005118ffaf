"""The per-chunk reconstruction map ``chunk_fn(y_chunk) -> tables_chunk`` of a BTF.

One :class:`ChunkFunction` is built per (configuration, parameters, sample geometry) and maps the
flat slice samples of a chunk of texels, ``(C, n, 3)`` in the order of the measurement store's
geometry, to their ABRDFs ``(C, 6561, 3)`` (``table[i, v]`` flattened ``i * 81 + v``). It is a
pure JAX function (an ``eqx.Module``): the batch driver jits it once with texel-axis shardings.

Backends:

- ``"operator"``: the fixed-parameter linear operator of :mod:`abrdf_jax._operator` (one matrix
  product per chunk, plus the per-texel nonlinearity of the value space), when that module exists
  and accepts the configuration;
- ``"pipeline"``: :func:`abrdf_jax.reconstruct_batch`, the vmapped pipeline (the RBF
  factorisation is shared by the texels of a chunk, the rest runs per texel);
- ``"auto"``: the operator where it applies, else the pipeline.

The flat samples are put into the slice layout of :class:`~abrdf_jax.Measurements` by a fixed
grouping matrix read off :func:`~abrdf_jax.group_slices` (which is linear in the values: it
places each sample, copies samples where the slices cross, averages repeated angles), so the
batch path groups the samples exactly as ``abrdf-jax reconstruct`` groups a CSV file.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError
from .._params import Config, Params
from .._pipeline import reconstruct_batch
from .._samples import Samples
from .._slices import Measurements, group_slices

BACKENDS = ("auto", "operator", "pipeline")
N_PAIRS = 81 * 81


def geometry_samples(geometry: dict) -> Samples:
    """The sample directions of a measurement store's geometry (values zero)."""
    try:
        cols = [np.asarray(geometry[k], float) for k in ("theta_i", "phi_i", "theta_v", "phi_v")]
    except KeyError as e:
        raise InputError(f"measurement geometry lacks {e.args[0]!r}") from None
    n = len(cols[0])
    if n == 0 or any(len(c) != n for c in cols):
        raise InputError("measurement geometry: theta_i, phi_i, theta_v, phi_v must have one equal, non-zero length")
    return Samples(*cols, np.zeros((n, 3)))


def grouping(geometry: dict, pairs, alpha_deg: float) -> tuple[Measurements, np.ndarray]:
    """Slice layout of a sample geometry and the matrix that fills it from flat samples.

    Returns:
        ``(template, G)``: ``template`` holds ``t``, ``count``, ``pairs``, ``has_axial`` (its
        values are zero); ``G`` has shape ``(S * nmax, n)`` with ``y_slices = G @ y_flat``.
    """
    base = geometry_samples(geometry)
    n = len(base)
    cols = []
    template = None
    for j0 in range(0, n, 3):
        rgb = np.zeros((n, 3))
        width = min(3, n - j0)
        rgb[j0 + np.arange(width), np.arange(width)] = 1.0
        s = Samples(base.theta_i, base.phi_i, base.theta_v, base.phi_v, rgb)
        meas, _ = group_slices(s, alpha_deg, pairs=pairs, dtype=np.float32)  # entries 0 or 1
        y = np.asarray(meas.y)
        cols.extend(y[..., c].reshape(-1) for c in range(width))
        if template is None:
            template = meas
    g = np.stack(cols, axis=1)
    template = Measurements(template.t, jnp.zeros_like(template.y), template.count, template.pairs,
                            template.has_axial)
    return template, g


def _operator_module():
    """``abrdf_jax._operator`` when it exists (another part of the package), else ``None``."""
    try:
        from .. import _operator
    except ImportError:
        return None
    return _operator if hasattr(_operator, "compile_operator") else None


class ChunkFunction(eqx.Module):
    """``chunk_fn(y) -> tables``: flat samples ``(C, n, 3)`` to ABRDFs ``(C, 6561, 3)``.

    Build with :func:`make_chunk_fn`. Pure and jit-able; holds everything that depends on the
    configuration, the parameters and the geometry (the grouping matrix, the operator).
    """

    backend: str = eqx.field(static=True)
    config: Config
    params: Params
    template: Measurements
    group: Float[Array, "P n"]
    operator: object = None
    source: Array | None = None  # operator input k is flat sample source[k]

    @property
    def n_samples(self) -> int:
        return self.group.shape[1]

    def measurements(self, y: Float[Array, "C n 3"]) -> Measurements:
        """Flat samples to a stacked :class:`Measurements` (leading texel axis)."""
        c = y.shape[0]
        s, nmax = self.template.t.shape
        ys = jnp.einsum("pn,cnk->cpk", self.group.astype(y.dtype), y).reshape(c, s, nmax, 3)
        t = jnp.broadcast_to(self.template.t.astype(y.dtype), (c, s, nmax))
        count = jnp.broadcast_to(self.template.count, (c, s))
        return Measurements(t, ys, count, self.template.pairs, self.template.has_axial)

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        if self.backend == "operator":
            # The operator reads the valid slice samples in its own order: a gather of the flat
            # samples, then one matrix product for the whole chunk.
            out = self.operator(y[:, self.source, :])
        else:
            out = reconstruct_batch(self.measurements(y), self.config, self.params)
        return out.reshape(y.shape[0], N_PAIRS, 3)


def make_chunk_fn(config: Config, params: Params, geometry: dict, backend: str = "auto",
                  dtype=jnp.float32) -> ChunkFunction:
    """Build the chunk map of one (configuration, parameters, sample geometry).

    Args:
        config: the reconstruction's discrete choices (its budget must match the geometry).
        params: α, widths, λ (α must be the geometry's slice offset).
        geometry: the measurement store's geometry (``theta_i`` … ``phi_v`` per sample,
            ``alpha_deg``, ``pairs``).
        backend: ``"auto"``, ``"operator"`` or ``"pipeline"`` (see the module docstring).
        dtype: working float dtype (float32 is the fast default).

    Returns:
        A :class:`ChunkFunction`.

    Raises:
        InputError: unknown backend; the operator asked for but not available or not
            applicable; a geometry that does not match the configuration's budget.
    """
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {BACKENDS}, got {backend!r}")
    alpha = float(geometry.get("alpha_deg", np.rad2deg(float(params.alpha))))
    template, group = grouping(geometry, config.pairs, alpha)
    if config.budget == "aniso204" and not template.has_axial:
        raise InputError("Config(budget='aniso204') needs axial slices, but the measurement geometry has none")
    template = Measurements(template.t.astype(dtype), template.y.astype(dtype), template.count,
                            template.pairs, template.has_axial)
    params = Params(jnp.asarray(params.alpha, dtype), jnp.asarray(params.widths, dtype),
                    jnp.asarray(params.reg, dtype))
    operator, source, why = None, None, None
    if backend in ("auto", "operator"):
        mod = _operator_module()
        if mod is None:
            why = "abrdf_jax._operator is not available"
        else:
            try:
                operator = mod.compile_operator(config, params, template)
            except (InputError, ValueError, NotImplementedError) as e:
                why = f"the operator does not apply: {e}"
        if operator is not None:
            rows = group[np.asarray(operator.index)]  # (n_in, n): which flat sample feeds each input
            if not np.all((rows == 0) | (rows == 1)) or not np.all(rows.sum(axis=1) == 1):
                operator, why = None, "repeated sample angles are averaged (not a plain gather)"
            else:
                source = jnp.asarray(np.argmax(rows, axis=1), jnp.int32)
        if operator is None and backend == "operator":
            raise InputError(f"backend='operator': {why}")
    chosen = "operator" if operator is not None else "pipeline"
    return ChunkFunction(chosen, config, params, template, jnp.asarray(group, dtype), operator, source)
