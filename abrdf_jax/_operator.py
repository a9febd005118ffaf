"""The fixed-parameter reconstruction compiled into one matrix (issue 4).

For a fixed :class:`Config`, fixed :class:`Params` and fixed sample positions (the slice
parameters ``t`` and counts of a template measurement, which the protocol fixes for a given α),
every step of :func:`abrdf_jax.reconstruct` from the sample values to the table is linear, except

- the value space: ``"log"`` takes the log *after* the subspace rule, ``"logsamples"`` before it;
- the rules ``"filip2012"`` (a min–max stretch) and ``"log"`` (multiplicative);
- the final clamp at 0.

With a linear rule (``"diagonal"``, always used by iso102; ``"average"``; ``"crossing"``) the map
is therefore ``table = max(post(M · pre(y)), 0)`` with one dense matrix ``M`` of shape
``(6561, n_in)`` (``n_in`` the valid samples, 102 for iso102, 204 for aniso204) and

- ``value_space="linear"``: ``pre``, ``post`` the identity;
- ``value_space="logsamples"``: ``pre(y) = ln(max(y, 0) + ε)``, ``post(z) = exp(z) − ε`` with
  ``ε = log_eps · mean |y|`` per material and channel (the pipeline's ε).

``M`` is built by running the pipeline's own linear part (:func:`subspace_values` and
:func:`rbf_map` of ``_pipeline.py``) on the ``n_in`` unit vectors at once, as ``n_in`` value
columns: one RBF factorisation, the same code as :func:`reconstruct`, so the two cannot drift. A
batch of ``B`` materials is then one matrix product ``(6561, n_in) · (n_in, 3B)``.

Settings that are not linear in the (log) samples — the rules ``"filip2012"`` and ``"log"``, or
``value_space="log"`` — raise :class:`InputError` unless ``nonlinear="two_stage"`` is asked for:
then the subspace step runs per material (vmapped, the pipeline's function) and only the RBF
step is a matrix, ``(6561, 1296)`` (13× the flops of the single-stage matrix for iso102). A linear
rule on ``"logsamples"`` (or on a dense layout) asked for two stages takes them too: the matrix
then serves every slice layout of its pairs (the command line's shared form, ``_engine``).

Validity: the operator reproduces :func:`reconstruct_batch` for measurements with the template's
slice parameters and counts (checked on the host when the input is a concrete
:class:`Measurements`; values passed as arrays are taken in the template's order, unchecked).
"""

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._build_jit import build_jit
from ._errors import InputError
from ._finite import check_concrete
from ._grid import _centre_target_index, centre_count, keep_centres, ubo_target_vectors
from ._host_build import NONLINEAR_MODES as NONLINEAR_MODES, BuiltMatrix as BuiltMatrix
from ._host_build import build_stage, host_matrix_or_none, sample_index, template_layout
from ._kept_rows import kept_columns, kept_product, kept_weights
from ._low_rank import low_rank_factors, product as _product
from ._measurements import Measurements
from ._params import Config, Params
from ._pipeline import fit_inputs, rbf_map, subspace_values
from ._smoothing import operator_neighbours, smooth_compact, smooths_slices
from ._spikes import cap_samples
from ._values import log_values, value_eps, value_space
from ._xp import to_device


#: How many times the operator's apply function and its builder were traced (tests use this to
#: prove that new data and new parameters do not recompile).
TRACE_COUNT = {"apply": 0, "build": 0}


class ReconstructionOperator(eqx.Module):
    """A compiled fixed-parameter reconstruction: call it on measurements or sample values.

    Attributes:
        matrix: ``(q, n_features)`` dense operator (``q`` = 6561 UBO pairs or the targets);
            ``n_features`` = ``n_in`` valid samples (single stage) or the RBF centres (two stage).
        index: ``(n_in,)`` flat index ``s · nmax + k`` of each valid sample of the template.
        keep: the output rows (flat ``i · 81 + v``) where the restored subspaces are kept (the
            centres that are UBO pairs; none at other targets): the spike cap's correction.
        t, count: the template's slice parameters ``(S, nmax)`` and counts ``(S,)``.
        params: the parameters it was built with (the two-stage path needs α).
        config: the static configuration.
        stage: ``"single"`` (the whole map is ``matrix``) or ``"two_stage"``.
        pairs, has_axial, centre_azimuths: the template's static layout.
        grid: whether the output is the 81×81 UBO table (else ``(q, C)`` at the targets).
        keep_columns: ``(k, nnz)`` the nonzero columns of each kept row of ``matrix``
            (:func:`kept_columns`), or ``None``: the kept rows' product is then dense.
        factors: ``(U, W)``, ``U · W = matrix`` with ``U`` ``(q, r)``, ``W`` ``(r, f)`` where
            the matrix's rank ``r`` is low enough to save work (:mod:`abrdf_jax._low_rank`):
            every product then runs through them; or ``None``.
        neighbours: the slice smoothing's neighbours of the valid samples, built on the host
            (``_smoothing.operator_neighbours``), or ``None`` (found when applied).
    """

    matrix: Float[Array, "q f"]
    index: Int[Array, " n_in"]
    keep: Int[Array, " k"]
    t: Float[Array, "S nmax"]
    count: Int[Array, " S"]
    params: Params
    config: Config = eqx.field(static=True)
    stage: str = eqx.field(static=True)
    pairs: tuple = eqx.field(static=True)
    has_axial: bool = eqx.field(static=True)
    grid: bool = eqx.field(static=True)
    centre_azimuths: int | None = eqx.field(static=True, default=None)
    keep_columns: Int[Array, "k nnz"] | None = None
    factors: tuple[Float[Array, "q r"], Float[Array, "r f"]] | None = None
    neighbours: tuple | None = None

    @property
    def n_inputs(self) -> int:
        """Number of sample values per channel the operator reads (``n_in``)."""
        return int(self.index.shape[0])

    @property
    def dtype(self):
        return self.matrix.dtype

    def compact(self, values) -> Float[Array, "... n_in C"]:
        """The valid sample values of measurements (a :class:`Measurements`, or its ``y``
        ``(..., S, nmax, C)``) in the operator's input order, ``(..., n_in, C)``: what
        :meth:`__call__` accepts fastest."""
        x, lead, full = self._inputs(values)
        return _to_compact(self, x, full).reshape(*lead, self.n_inputs, x.shape[-1])

    def _inputs(self, values):
        """``(x, lead, full)``: values flattened to one batch axis, the leading shape, and whether
        they are in the slice layout ``(S, nmax)`` (else compact ``(n_in,)``)."""
        if isinstance(values, Measurements):
            self._check_layout(values)
            values = values.y
        x = jnp.asarray(values)
        s, nmax = self.t.shape
        if x.ndim >= 3 and x.shape[-3:-1] == (s, nmax):
            lead, full = x.shape[:-3], True
        elif x.ndim >= 2 and x.shape[-2] == self.n_inputs:
            lead, full = x.shape[:-2], False
        else:
            raise InputError(
                f"values must have shape (..., {s}, {nmax}, C) or (..., {self.n_inputs}, C), got {x.shape}"
            )
        return x.reshape(-1, *x.shape[len(lead) :]), lead, full

    def _check_layout(self, meas: Measurements) -> None:
        if meas.pairs != self.pairs:
            raise InputError(
                f"measurement pairs {meas.pairs} differ from the operator's {self.pairs}"
            )
        if meas.centre_azimuths != self.centre_azimuths:
            raise InputError(
                f"measurement's RBF centre layout (centre_azimuths={meas.centre_azimuths}) differs "
                f"from the operator's ({self.centre_azimuths}); compile a new operator"
            )
        if meas.t.shape[-2:] != self.t.shape:
            raise InputError(
                f"measurement slices have shape {meas.t.shape[-2:]}, the operator expects {self.t.shape}"
            )
        if isinstance(meas.t, jax.core.Tracer) or isinstance(meas.count, jax.core.Tracer):
            return  # under a user's jit: the caller vouches for the layout
        count = np.asarray(meas.count).reshape(-1, self.count.shape[0])
        if not np.all(count == np.asarray(self.count)[None]):
            raise InputError(
                "measurement sample counts differ from the operator's template; compile a new operator"
            )
        t = np.asarray(meas.t).reshape(-1, *self.t.shape)
        valid = np.arange(self.t.shape[1])[None, :] < np.asarray(self.count)[:, None]
        tol = 1e-5 if t.dtype == np.float32 or self.t.dtype == jnp.float32 else 1e-9
        if not np.all(np.abs(np.where(valid[None], t - np.asarray(self.t)[None], 0.0)) <= tol):
            raise InputError(
                "measurement slice positions differ from the operator's template (another α or "
                "sampling?); compile a new operator"
            )

    def __call__(self, values, *, out=None) -> Float[Array, "... 81 81 C"]:
        """Reconstruct from measurements or sample values with one matrix product per batch.

        Args:
            values: a :class:`Measurements` with the template's layout (one, or stacked with a
                leading material axis), its ``y`` array ``(..., S, nmax, C)``, or compact values
                ``(..., n_in, C)`` in the order of :meth:`compact`.
            out: optionally an earlier result of the same shape and dtype whose memory the
                result reuses. It is *consumed* (donated: deleted, do not read it afterwards).
                For streams of large batches: a fresh output of 10,000 tables (787 MB float32)
                costs more in first-touch page faults than the matrix product itself.

        Returns:
            ``(..., 81, 81, C)`` tables (or ``(..., q, C)`` at the operator's targets), in the
            operator's dtype. Batches larger than :data:`TILE` are computed :data:`TILE`
            materials at a time (see :func:`_apply`); every result is the same to float32
            rounding whatever the batch.

        Raises:
            InputError: for a shape or a measurement layout that does not fit the template, an
                ``out`` of another shape or dtype, or NaN/inf in numpy ``values``. JAX arrays
                are not checked here (the hot path: ``benchmarks/finite_check.py``); a
                :class:`Measurements` was checked when made; where values may be bad, call
                ``op(abrdf_jax.require_finite(values))``, which also works inside a ``jit``.
        """
        if isinstance(values, np.ndarray):  # host values: checked in numpy, no device sync
            check_concrete(values, "values")
        x, lead, full = self._inputs(values)
        x = x.astype(self.dtype)
        if out is None:
            res = _apply(self, x, full)
        else:
            shape = (*lead, *((81, 81) if self.grid else (self.matrix.shape[0],)), x.shape[-1])
            if tuple(out.shape) != shape or out.dtype != self.dtype:
                raise InputError(
                    f"out must have shape {shape} and dtype {self.dtype}, got "
                    f"{tuple(out.shape)} {out.dtype}"
                )
            arrays, static = eqx.partition(self, eqx.is_array)
            res = _apply_into(
                arrays, static, x, full, jnp.reshape(out, (x.shape[0], *shape[len(lead) :]))
            )
        return res.reshape(*lead, *res.shape[1:])


def _to_compact(op: ReconstructionOperator, x, full: bool):
    if not full:
        return x
    s, nmax = op.t.shape
    return x.reshape(x.shape[0], s * nmax, x.shape[-1])[:, op.index, :]


def _rows(z: Float[Array, "B f C"]) -> Float[Array, "BC f"]:
    """Features ``(B, f, C)`` as GEMM rows ``(B·C, f)``: every material and channel is a row."""
    b, f, c = z.shape
    return jnp.transpose(z, (0, 2, 1)).reshape(b * c, f)


def _unrows(out: Float[Array, "BC q"], b: int) -> Float[Array, "B q C"]:
    """GEMM rows ``(B·C, q)`` back to ``(B, q, C)``.

    The GEMM order ``(B·C, f) · (f, q)`` leaves only a small ``(C, q) → (q, C)`` transpose per
    material, which XLA fuses with the exp and the clamp; ``(q, f) · (f, B·C)`` would need a
    strided ``(q, B) → (B, q)`` transpose of the whole output (measured ~1.7× slower for
    B = 1000 on CPU).
    """
    return jnp.transpose(out.reshape(b, -1, out.shape[-1]), (0, 2, 1))


#: Materials per matrix product in a large batch: ``(3·TILE, n_in) · (n_in, 6561)`` runs at the
#: machine's GEMM rate and its output (10 MB float32) stays in the last-level cache, where the
#: exp, clamp and ``(C, q) → (q, C)`` transpose read it (``python -m benchmarks.throughput``).
TILE = 128


def _decoded(op: ReconstructionOperator, vs, z, zc, eps, kept=None):
    """Features ``z`` ``(T, f, C)`` of ``T`` materials to their outputs ``(T, q, C)``.

    With the spike cap (``zc``: the features the RBF fits, ``_spikes.py``) the map is
    ``M · zc`` except at the rows where the restored subspaces are kept: there the uncapped
    restoration ``M[keep] · z`` goes back, as in the pipeline (those rows of ``M`` are the
    restoration itself; ``M · zc + M[keep] · (z − zc)`` there, within float32 rounding, but
    set rather than added: no read of the product). The kept rows are set in the GEMM's own
    row layout, before the transpose that XLA fuses with the exp (set after it, the transposed
    product is written out once more: ``python -m benchmarks.btf``'s chunk map 15 % slower).
    ``kept`` is :func:`~._kept_rows.kept_weights`, taken once per call."""
    if zc is None:
        return vs.decode(_unrows(_product(op.matrix, _rows(z), op.factors), z.shape[0]), eps)
    lin = _product(op.matrix, _rows(zc), op.factors)
    if op.keep.shape[0]:
        kept = kept_weights(op) if kept is None else kept
        rows = _rows(z)
        cols = op.keep_columns
        fix = _product(kept, rows) if cols is None else kept_product(kept, cols, rows)
        lin = lin.at[:, op.keep].set(fix, unique_indices=True)
    return vs.decode(_unrows(lin, z.shape[0]), eps)


def _tiled(op: ReconstructionOperator, vs, z, zc, eps, out, kept=None):
    """:func:`_decoded` of a batch, :data:`TILE` materials at a time, written into ``out``.

    One GEMM over the whole batch writes its ``(B·C, q)`` product to memory and reads it back
    for the exp and the transpose (at B = 1,000, 79 MB that no cache holds); a loop over tiles
    keeps each product in cache and writes each output once, in place (``out`` is the loop's
    carried buffer: a donated earlier result, else zeros). The last tile ends at the batch's
    end and overlaps the one before it (its first materials are computed twice, the same
    way): one tile shape, and no out-of-place update after the loop (that would copy ``out``).
    """
    b = z.shape[0]
    size = min(TILE, b)

    def step(i, out):
        start = jnp.minimum(i * size, b - size)
        zt = jax.lax.dynamic_slice_in_dim(z, start, size)
        ct = None if zc is None else jax.lax.dynamic_slice_in_dim(zc, start, size)
        et = None if eps is None else jax.lax.dynamic_slice_in_dim(eps, start, size)
        res = _decoded(op, vs, zt, ct, et, kept)
        return jax.lax.dynamic_update_slice_in_dim(out, res, start, 0)

    return jax.lax.fori_loop(0, -(-b // size), step, out)


def _apply_impl(op: ReconstructionOperator, x, full: bool, out=None):
    TRACE_COUNT["apply"] += 1
    cfg = op.config
    vs = value_space(cfg.value_space)
    x = _to_compact(op, x, full)
    b, n_in, c = x.shape
    # ε from the valid samples of each material, as the pipeline's (B, 1, C)
    eps = (
        value_eps(jnp.mean(jnp.abs(x), axis=1), cfg.log_eps, x.dtype)[:, None, :]
        if vs.is_log
        else None
    )
    if op.stage == "single":
        z = log_values(x, eps) if vs.log_samples else x  # single stage: never log after the rule
        if smooths_slices(cfg):  # the pipeline's slice smoothing (_pipeline.smoothed_samples)
            z = smooth_compact(
                cfg.slice_smoothing, z, op.index, op.t.astype(x.dtype), op.count, nb=op.neighbours
            )
        zc = cap_samples(z, cfg.spike_cap) if vs.log_samples and cfg.spike_cap else None
    else:
        s, nmax = op.t.shape
        full_y = (
            jnp.zeros((b, s * nmax, c), x.dtype).at[:, op.index, :].set(x).reshape(b, s, nmax, c)
        )
        template = Measurements(
            op.t.astype(x.dtype), full_y[0], op.count, op.pairs, op.has_axial, op.centre_azimuths
        )
        p = op.params.astype(x.dtype)

        def features(y, e):
            return fit_inputs(template.replace(y=y), cfg, p, vs, e)[1:]

        z, zc = jax.vmap(features)(full_y, eps)
    q = op.matrix.shape[0]
    if out is None and b <= TILE:
        res = _decoded(op, vs, z, zc, eps)
    else:
        out = jnp.zeros((b, q, c), x.dtype) if out is None else out.reshape(b, q, c)
        kept = None if zc is None else kept_weights(op)  # once, not per tile
        res = _tiled(op, vs, z, zc, eps, out, kept)
    if op.grid:
        res = res.reshape(b, 81, 81, c)
    return res


_apply = eqx.filter_jit(_apply_impl)


@partial(jax.jit, static_argnums=(1, 3), donate_argnums=(4,))
def _apply_into(arrays, static, x, full: bool, out):
    """:func:`_apply` writing into the donated buffer ``out`` (``(B, ...)`` like the result)."""
    return _apply_impl(eqx.combine(arrays, static), x, full, out)


@build_jit
def _build(
    t,
    count,
    index,
    params: Params,
    config: Config,
    pairs,
    has_axial,
    targets,
    grid_wi,
    grid_wv,
    stage: str,
    dtype,
    azimuths=None,
):
    TRACE_COUNT["build"] += 1
    # Params or numpy ParamValues (the command line's): made traced Params here, not eagerly.
    params = Params(*(jnp.asarray(v, dtype) for v in (params.alpha, params.widths, params.reg)))
    if stage == "single":
        s, nmax = t.shape
        n_in = index.shape[0]
        # Unit sample vectors as n_in value columns: one pass through the pipeline's linear part.
        unit = (
            jnp.zeros((s * nmax, n_in), dtype)
            .at[index, jnp.arange(n_in)]
            .set(1.0)
            .reshape(s, nmax, n_in)
        )
        vals = subspace_values(
            Measurements(t.astype(dtype), unit, count, pairs, has_axial, azimuths), config, params
        )
    else:
        vals = jnp.eye(centre_count(pairs, azimuths), dtype=dtype)
    if targets is not None:
        return rbf_map(vals, pairs, config, params, targets, azimuths=azimuths)
    # The UBO targets come in as arguments, not constants: XLA would constant-fold their
    # coordinates and polynomial tail for tens of seconds.
    out = rbf_map(vals, pairs, config, params, (grid_wi, grid_wv), azimuths=azimuths)
    return keep_centres(out, vals, pairs, azimuths)


def operator_matrix(
    config: Config, params, template, *, build_dtype, targets=None, nonlinear="raise"
) -> BuiltMatrix:
    """The :class:`BuiltMatrix` of :func:`compile_operator`, from host inputs.

    ``params`` may be :class:`Params` or numpy ``ParamValues`` and ``template`` anything with
    the slice arrays of a :class:`Measurements` (``t``, ``count``, ``pairs``, ``has_axial``,
    ``centre_azimuths``; numpy or JAX): the inputs go into the one compiled build as they are,
    so a build from numpy inputs (the operator store's, ``abrdf_jax._cache.build_entry``)
    dispatches no eager JAX operation (each of which compiles a small program on a cold call).
    """
    stage = build_stage(config, template, nonlinear)
    t, count = template_layout(template)
    index = sample_index(t, count)
    if targets is not None:
        targets = tuple(jnp.asarray(v, build_dtype) for v in targets)
        if (
            len(targets) != 2
            or targets[0].shape != targets[1].shape
            or targets[0].shape[-1:] != (3,)
        ):
            raise InputError("targets must be (wi, wv) unit vectors of equal shape (q, 3)")
    grid_wi, grid_wv = ubo_target_vectors(build_dtype, xp=np)
    values = params if isinstance(params, Params) else type(params)(*map(np.asarray, params))
    matrix = _build(
        t, count, index, values, config, template.pairs, template.has_axial, targets,
        grid_wi, grid_wv, stage, jnp.dtype(build_dtype), template.centre_azimuths,
    )  # fmt: skip
    keep = _centre_target_index(template.pairs, template.centre_azimuths)[1]
    keep = keep if targets is None else np.zeros(0, int)
    return BuiltMatrix(matrix, index, keep, stage, t, count)


def compile_operator(
    config: Config,
    params: Params,
    template: Measurements,
    *,
    dtype=None,
    build_dtype="host",
    targets: tuple[Float[Array, "q 3"], Float[Array, "q 3"]] | None = None,
    nonlinear: str = "raise",
) -> ReconstructionOperator:
    """Compile the fixed-parameter reconstruction into a :class:`ReconstructionOperator`.

    Args:
        config: the reconstruction's static choices; its rule must be linear
            (``"diagonal"``/iso102, ``"average"``, ``"crossing"``) and its value space
            ``"linear"`` or ``"logsamples"``, unless ``nonlinear="two_stage"``.
        params: α, widths and λ (fixed in the operator).
        template: one measurement (unbatched, or a stack whose members share one layout) whose
            slice parameters and counts every later input shares, e.g. ``sample(..., as_measurements=True)``.
        dtype: dtype of the operator and its outputs; default the template's.
        build_dtype: dtype in which the matrix is computed in JAX (then cast to ``dtype``).
            Default ``"host"`` (``None`` alike): float64 in numpy without JAX (the command line's build,
            :func:`abrdf_jax._host_build.host_matrix`: no compilation on a cold call, a float32
            operator then matches the float64 reconstruction to float32 rounding, and its
            low-rank factors can be read off, :mod:`abrdf_jax._low_rank`) where the setting
            allows it (the UBO grid, either stage, concrete parameters and template, an RBF
            system that is not singular), else JAX in float64 when ``jax_enable_x64`` is on,
            else in ``dtype``.
        targets: ``(wi, wv)`` unit vectors ``(q, 3)``: evaluate there instead of the UBO grid.
        nonlinear: ``"raise"`` (default) for settings that are not linear in the (log) samples,
            or ``"two_stage"``: per-material subspace step, then the RBF matrix.

    Returns:
        The operator; ``op(measurements_or_values)`` returns ``(..., 81, 81, C)`` tables.

    Raises:
        InputError: for a nonlinear setting with ``nonlinear="raise"``, or a bad template.
    """
    if not isinstance(config, Config) or not isinstance(params, Params):
        raise InputError("compile_operator needs a Config and a Params")
    if not isinstance(template, Measurements):
        raise InputError(f"template must be a Measurements, got {type(template).__name__}")
    dtype = jnp.dtype(dtype or template.y.dtype)
    built = None
    if build_dtype is None or (isinstance(build_dtype, str) and build_dtype == "host"):
        build_dtype = None
        concrete = not any(
            isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves((params, template))
        )
        if concrete and targets is None:
            built = host_matrix_or_none(config, params, template, nonlinear)
    if build_dtype is None:
        build_dtype = jnp.float64 if jax.config.jax_enable_x64 else dtype
    if built is None:
        built = operator_matrix(
            config, params, template, build_dtype=build_dtype, targets=targets, nonlinear=nonlinear
        )
    factors = low_rank_factors(built.matrix)

    host = built.matrix  # cast in numpy where built there; the kept rows' columns read off it
    host = host.astype(dtype) if isinstance(host, np.ndarray) else host
    cols, matrix = kept_columns(host, built.keep), jnp.asarray(host, dtype)
    return ReconstructionOperator(
        matrix,
        to_device(built.index, jnp.int32),
        to_device(built.keep, jnp.int32),
        to_device(built.t, dtype),
        to_device(built.count, jnp.int32),
        params.astype(dtype),
        config,
        built.stage,
        template.pairs,
        template.has_axial,
        targets is None,
        template.centre_azimuths,
        None if cols is None else to_device(cols, jnp.int32),
        None if factors is None else tuple(to_device(a, dtype) for a in factors),
        operator_neighbours(config, built, dtype),
    )
