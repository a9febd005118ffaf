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

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError
from .._grouping import grouping_matrix
from .._measurements import Measurements
from .._names import BTF_BACKENDS as BACKENDS
from .._operator import compile_operator
from .._params import Config, Params
from .._pipeline import reconstruct_batch
from ..select._isotropy import LEVEL, MIN_EFFECT, isotropy_batch
from ._store import ANGLES

N_PAIRS = 81 * 81


def grouping(geometry: dict, pairs, alpha_deg: float) -> tuple[Measurements, np.ndarray]:
    """Slice layout of a sample geometry and the matrix that fills it from flat samples.

    Returns:
        ``(template, G)``: ``template`` holds ``t``, ``count``, ``pairs``, ``has_axial`` (its
        values are zero); ``G`` has shape ``(S * nmax, n)`` with ``y_slices = G @ y_flat``.
    """
    try:
        angles = [np.asarray(geometry[k], float) for k in ANGLES]
    except KeyError as e:
        raise InputError(f"measurement geometry lacks {e.args[0]!r}") from None
    n = len(angles[0])
    if n == 0 or any(len(c) != n for c in angles):
        raise InputError(
            "measurement geometry: theta_i, phi_i, theta_v, phi_v must have one equal, non-zero length"
        )
    slices, g = grouping_matrix(angles, alpha_deg, pairs)
    return slices.to_measurements(), g


def _alpha_deg(geometry: dict, params: Params) -> float:
    return float(geometry.get("alpha_deg", np.rad2deg(float(params.alpha))))


def _slice_values(group, t_shape, y):
    """Flat samples ``y`` ``(C, n, 3)`` to slice values ``(C, S, nmax, 3)`` (``y_slices = G @ y``)."""
    return jnp.einsum("pn,cnk->cpk", group.astype(y.dtype), y).reshape(y.shape[0], *t_shape, 3)


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

    def measurements(self, y: Float[Array, "C n 3"]) -> Measurements:
        """Flat samples to a stacked :class:`Measurements` (leading texel axis)."""
        (c, *_), tm = y.shape, self.template
        t = jnp.broadcast_to(tm.t.astype(y.dtype), (c, *tm.t.shape))
        count = jnp.broadcast_to(tm.count, (c, *tm.count.shape))
        return tm.replace(y=_slice_values(self.group, tm.t.shape, y), t=t, count=count)

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        if self.backend == "operator":
            # The operator reads the valid slice samples in its own order: a gather of the flat
            # samples, then one matrix product for the whole chunk.
            out = self.operator(y[:, self.source, :])
        else:
            out = reconstruct_batch(self.measurements(y), self.config, self.params)
        return out.reshape(y.shape[0], N_PAIRS, 3)


def make_chunk_fn(
    config: Config, params: Params, geometry: dict, backend: str = "auto", dtype=jnp.float32
) -> ChunkFunction:
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
    template, group = grouping(geometry, config.pairs, _alpha_deg(geometry, params))
    if config.budget == "aniso204" and not template.has_axial:
        raise InputError(
            "Config(budget='aniso204') needs axial slices, but the measurement geometry has none"
        )
    template, params = template.astype(dtype), params.astype(dtype)
    operator, source, why = None, None, None
    if backend in ("auto", "operator"):
        try:
            # built in float64 numpy (no compile; float32 rounding of the float64 operator)
            operator = compile_operator(config, params, template)  # float64 numpy build
        except InputError as e:
            why = f"the operator does not apply: {e}"
        if operator is not None:
            # (n_in, n): which flat sample feeds each input
            rows = group[np.asarray(operator.index)]
            if not np.all((rows == 0) | (rows == 1)) or not np.all(rows.sum(axis=1) == 1):
                operator, why = None, "repeated sample angles are averaged (not a plain gather)"
            else:
                source = jnp.asarray(np.argmax(rows, axis=1), jnp.int32)
        if operator is None and backend == "operator":
            raise InputError(f"backend='operator': {why}")
    chosen = "operator" if operator is not None else "pipeline"
    group = jnp.asarray(group, dtype)
    return ChunkFunction(chosen, config, params, template, group, operator, source)


def texel_isotropy(group, t, count, y, *, level: float = LEVEL, min_effect: float = MIN_EFFECT):
    """The isotropy test of every texel: flat samples ``y`` ``(C, n, 3)`` put into the slice layout
    ``(t, count)`` by the grouping matrix ``group`` (:func:`grouping`), then
    :func:`abrdf_jax.select._isotropy.isotropy_batch`. Returns ``(isotropic, statistic, effect)``."""
    ys = _slice_values(group, t.shape, y)
    return isotropy_batch(ys, t, count, level=level, min_effect=min_effect)


class ModelChoiceChunkFunction(eqx.Module):
    """Per-texel model choice: the isotropy test of :mod:`abrdf_jax.select` on every texel.

    Each texel's axial slices are tested (:func:`abrdf_jax.select._isotropy.isotropy_batch`, the test
    ``abrdf-jax reconstruct --model auto`` runs on one material, noise estimated per texel); an
    isotropic texel gets the bivariate model on every sample (as ``reconstruct --model auto``
    gives an isotropic file; :mod:`abrdf_jax.btf._bivariate`), the others the anisotropic one.
    Both are compiled chunk maps; on a chunk both run and each texel keeps its own (two matrix
    products per chunk with the operator backend; a branch per texel would serialise the batch).

    Build with :func:`make_model_choice_fn`.
    """

    aniso: ChunkFunction
    iso: eqx.Module  # a BivariateChunkFunction, or a ChunkFunction of an iso102 configuration
    t: tuple = eqx.field(static=True)
    count: tuple = eqx.field(static=True)
    level: float = eqx.field(static=True)
    min_effect: float = eqx.field(static=True)

    @property
    def backend(self) -> str:
        return f"{self.aniso.backend}+choice"

    def isotropic(self, y: Float[Array, "C n 3"]):
        """``(isotropic, statistic, effect)`` per texel of flat samples ``y`` (the test's outputs)."""
        t, count = np.asarray(self.t), np.asarray(self.count)
        return texel_isotropy(
            self.aniso.group, t, count, y, level=self.level, min_effect=self.min_effect
        )

    def __call__(self, y: Float[Array, "C n 3"]) -> Float[Array, "C 6561 3"]:
        iso = self.isotropic(y)[0]
        return jnp.where(iso[:, None, None], self.iso(y), self.aniso(y))


def make_model_choice_fn(
    config: Config,
    params: Params,
    geometry: dict,
    backend: str = "auto",
    dtype=jnp.float32,
    *,
    iso_config: Config | None = None,
    iso_params: Params | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
) -> ModelChoiceChunkFunction:
    """Build the per-texel model-choice map (see :class:`ModelChoiceChunkFunction`).

    Args:
        config, params: the anisotropic model (budget ``aniso204``; the geometry must have axial
            slices).
        geometry, backend, dtype: as :func:`make_chunk_fn`.
        iso_config, iso_params: an RBF model of the isotropic texels (``iso_params`` default:
            its default parameters at the geometry's α); default the bivariate model
            (:func:`~abrdf_jax.btf.make_bivariate_chunk_fn`).
        level, min_effect: thresholds of the isotropy test (defaults of :mod:`abrdf_jax.select`).

    Raises:
        InputError: the anisotropic configuration is not ``aniso204`` or the geometry has no
            axial slice (nothing to test).
    """
    if config.budget != "aniso204":
        raise InputError(
            f"model='auto' chooses between iso102 and aniso204 per texel; the configuration's "
            f"budget is {config.budget!r} (use model='fixed')"
        )
    aniso = make_chunk_fn(config, params, geometry, backend, dtype)
    if iso_config is None:
        from ._bivariate import make_bivariate_chunk_fn

        iso = make_bivariate_chunk_fn(geometry, dtype)
    else:
        if iso_params is None:
            alpha_deg = _alpha_deg(geometry, params)
            iso_params = Params.default(iso_config, alpha_deg=alpha_deg, dtype=dtype)
        iso = make_chunk_fn(iso_config, iso_params, geometry, backend, dtype)
    t = tuple(tuple(float(v) for v in row) for row in np.asarray(aniso.template.t, np.float64))
    count = tuple(int(c) for c in np.asarray(aniso.template.count))
    return ModelChoiceChunkFunction(aniso, iso, t, count, float(level), float(min_effect))
