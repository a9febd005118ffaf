"""The reconstruction pipeline: measurements → slices → toroidal subspaces → RBF → ABRDF table.

``reconstruct`` is a pure function of a :class:`Measurements` pytree (the sample values and their
slice positions), a static :class:`Config` and traced :class:`Params` (α, kernel widths,
regularisation): it is jit-compiled once per configuration and shape, differentiable in the
parameters and the values, and vmaps over materials (``reconstruct_batch``), where the RBF
factorisation is shared because it depends on the parameters only.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._errors import InputError
from ._grid import UBO_COUNTS, UBO_THETAS_DEG, half_diff, onion_from_vector, pair_grid, to_vector, ubo_grid
from ._params import Config, Params
from ._rbf import SolveInfo, fit_rbf, fit_rbf_info
from ._samples import Samples
from ._slices import Measurements, group_slices, stack_measurements
from ._subspace import subspace


def ring_azimuths_deg(theta_deg: float) -> np.ndarray:
    """Azimuths of the UBO ring at ``theta_deg``; 24 uniform azimuths off the grid's rings."""
    for t, n in zip(UBO_THETAS_DEG, UBO_COUNTS):
        if np.isclose(t, theta_deg):
            return np.arange(n) * 360.0 / n
    return np.arange(24) * 15.0


def centre_layout(pairs) -> list[tuple[np.ndarray, np.ndarray]]:
    """RBF centres: per elevation pair, every (φi, φv) of the two rings (degrees), flattened."""
    out = []
    for ti, tv in pairs:
        ai, av = ring_azimuths_deg(ti), ring_azimuths_deg(tv)
        out.append((np.repeat(ai, len(av)), np.tile(av, len(ai))))
    return out


def centre_vectors(pairs, dtype):
    wi, wv = [], []
    for (ti, tv), (pi_, pv) in zip(pairs, centre_layout(pairs)):
        wi.append(to_vector(np.full(len(pi_), np.deg2rad(ti)), np.deg2rad(pi_)))
        wv.append(to_vector(np.full(len(pv), np.deg2rad(tv)), np.deg2rad(pv)))
    return jnp.concatenate(wi).astype(dtype), jnp.concatenate(wv).astype(dtype)


def pair_coordinates(wi: Float[Array, "q 3"], wv: Float[Array, "q 3"], parameterization: str) -> Float[Array, "q 4"]:
    """Coordinates of direction pairs for the RBF (see :class:`Config`)."""
    if parameterization == "onion":
        return jnp.concatenate([onion_from_vector(wi), onion_from_vector(wv)], axis=-1)
    if parameterization == "spherical":
        from ._grid import from_vector

        ti, pi_ = from_vector(wi)
        tv, pv = from_vector(wv)
        return jnp.stack([ti, pi_, tv, pv], axis=-1)
    if parameterization == "halfdiff":
        return half_diff(wi, wv)
    raise ValueError(f"unknown parameterization {parameterization!r}")


def ubo_target_vectors(dtype):
    ti, pi_, tv, pv = pair_grid()
    wi = to_vector(np.deg2rad(ti), np.deg2rad(pi_))
    wv = to_vector(np.deg2rad(tv), np.deg2rad(pv))
    return jnp.asarray(wi, dtype), jnp.asarray(wv, dtype)


def _centre_target_index(pairs) -> np.ndarray | None:
    """Flat UBO pair index (i*81 + v) of every centre, or None if a pair is off the grid."""
    theta, phi = ubo_grid()
    idx = []
    for (ti, tv), (pi_, pv) in zip(pairs, centre_layout(pairs)):
        for a, b in zip(pi_, pv):
            ii = np.nonzero(np.isclose(theta, ti) & np.isclose(phi, a))[0]
            vv = np.nonzero(np.isclose(theta, tv) & np.isclose(phi, b))[0]
            if len(ii) != 1 or len(vv) != 1:
                return None
            idx.append(ii[0] * 81 + vv[0])
    return np.asarray(idx)


def subspace_values(meas: Measurements, config: Config, params: Params) -> Float[Array, "n 3"]:
    """Values of the reconstructed toroidal subspaces at the RBF centres (eq. 2–5)."""
    vals = []
    alpha = params.alpha.astype(meas.y.dtype)
    for p, (pi_, pv) in enumerate(centre_layout(meas.pairs)):
        vals.append(
            subspace(
                meas.t[2 * p], meas.y[2 * p], meas.count[2 * p],
                meas.t[2 * p + 1], meas.y[2 * p + 1], meas.count[2 * p + 1],
                jnp.asarray(np.deg2rad(pi_), meas.y.dtype), jnp.asarray(np.deg2rad(pv), meas.y.dtype),
                alpha, rule=config.subspace_rule, interp=config.interp,
            )
        )
    return jnp.concatenate(vals)


def value_eps(mean_abs, log_eps: float, dtype):
    """ε of the log value spaces: ``log_eps`` times the mean absolute sample, per channel."""
    return log_eps * mean_abs + jnp.finfo(dtype).tiny ** 0.5


def _value_eps(meas: Measurements, config: Config):
    valid = (jnp.arange(meas.y.shape[1])[None, :] < meas.count[:, None])[..., None]
    mean = jnp.sum(jnp.where(valid, jnp.abs(meas.y), 0.0), axis=(0, 1)) / jnp.maximum(jnp.sum(meas.count), 1)
    return value_eps(mean, config.log_eps, meas.y.dtype)


def log_values(x, eps):
    """``ln(max(x, 0) + ε)``: the values the RBF sees in the log value spaces."""
    return jnp.log(jnp.maximum(x, 0.0) + eps)


def log_samples(meas: Measurements, eps) -> Measurements:
    """The measurement with every valid sample replaced by ``ln(max(y, 0) + ε)`` (padding stays 0)."""
    valid = (jnp.arange(meas.y.shape[1])[None, :] < meas.count[:, None])[..., None]
    y = jnp.where(valid, log_values(meas.y, eps), 0.0)
    return Measurements(meas.t, y, meas.count, meas.pairs, meas.has_axial)


def keep_centres(out: Float[Array, "q C"], vals: Float[Array, "n C"], pairs) -> Float[Array, "q C"]:
    """Put the reconstructed subspaces back at their UBO grid pairs (the paper's step 3 fills
    only the missing values); a no-op when a pair is off the grid."""
    idx = _centre_target_index(pairs)
    return out if idx is None else out.at[idx].set(vals)


def rbf_map(fit_vals: Float[Array, "n C"], pairs, config: Config, params: Params, targets=None, keep: bool = True):
    """RBF fit at the centres of ``pairs`` and evaluation at the targets: linear in ``fit_vals``.

    Args:
        fit_vals: values at the RBF centres (``centre_layout(pairs)`` order), any number of columns.
        targets: ``(wi, wv)`` or ``None`` for the 6561 UBO pairs (then ``keep`` puts ``fit_vals``
            back at the centres' grid pairs).

    Returns:
        ``(q, C)`` values in the fit space (before any exp).
    """
    dtype = fit_vals.dtype
    wi_c, wv_c = centre_vectors(pairs, dtype)
    xc = pair_coordinates(wi_c, wv_c, config.parameterization)
    rbf = fit_rbf(xc, fit_vals, params.widths.astype(dtype), config.kernel, params.reg.astype(dtype), config.degree)
    wi_t, wv_t = ubo_target_vectors(dtype) if targets is None else targets
    out = rbf(pair_coordinates(wi_t, wv_t, config.parameterization))
    if targets is None and keep:
        out = keep_centres(out, fit_vals, pairs)
    return out


def _reconstruct_core(meas: Measurements, config: Config, params: Params, targets=None):
    log_space = config.value_space in ("log", "logsamples")
    eps = _value_eps(meas, config) if log_space else None
    if config.value_space == "logsamples":
        # The log is taken of the samples, before slice interpolation and the subspace rule:
        # everything from ln(y + ε) to the RBF output is then linear (see _operator.py).
        meas = log_samples(meas, eps)
    vals = subspace_values(meas, config, params)
    if config.value_space == "log":
        out = jnp.exp(rbf_map(log_values(vals, eps), meas.pairs, config, params, targets, keep=False)) - eps
        if targets is None:
            out = keep_centres(out, vals, meas.pairs)
    else:
        out = rbf_map(vals, meas.pairs, config, params, targets, keep=True)
        if config.value_space == "logsamples":
            out = jnp.exp(out) - eps
    if targets is None:
        out = out.reshape(81, 81, out.shape[-1])
    # An ABRDF is non-negative: negative values are interpolation overshoot.
    return jnp.maximum(out, 0.0)


_reconstruct_jit = eqx.filter_jit(_reconstruct_core)


@eqx.filter_jit
def _reconstruct_batch_jit(meas, config, params, targets=None):
    return jax.vmap(lambda m: _reconstruct_core(m, config, params, targets))(meas)


def infer_budget(samples: Samples | Measurements, alpha_deg: float | None = None) -> str:
    """``"aniso204"`` when axial slices were measured, else ``"iso102"``."""
    if isinstance(samples, Samples):
        samples, _ = group_slices(samples, alpha_deg)
    return "aniso204" if samples.has_axial else "iso102"


def prepare(samples: Samples | Measurements, config: Config | None, params: Params | None, dtype=None):
    """Group samples into slices and resolve the defaults of ``config`` and ``params``."""
    if isinstance(samples, Samples):
        alpha = None if params is None else params.alpha_deg
        pairs = (config or Config()).pairs
        kw = {} if dtype is None else {"dtype": dtype}
        meas, report = group_slices(samples, alpha, pairs=pairs, **kw)
        if params is None:
            params = Params.default(config, alpha_deg=report["alpha_deg"])
    elif isinstance(samples, Measurements):
        meas = samples
    else:
        raise InputError(f"samples must be Samples or Measurements, got {type(samples).__name__}")
    if config is None:
        config = Config(budget="aniso204" if meas.has_axial else "iso102")
    if config.budget == "aniso204" and not meas.has_axial:
        raise InputError("Config(budget='aniso204') needs axial slices, but the measurement has none; use budget='iso102'")
    if params is None:
        params = Params.default(config)
    return meas, config, params


def reconstruct(
    samples: Samples | Measurements,
    config: Config | None = None,
    params: Params | None = None,
    *,
    targets: tuple[Float[Array, "q 3"], Float[Array, "q 3"]] | None = None,
) -> Float[Array, "81 81 3"]:
    """Reconstruct a full ABRDF from slice measurements (Filip 2012).

    Args:
        samples: measured samples (:class:`Samples`, grouped into slices here) or already grouped
            :class:`Measurements` (needed under ``jax.jit``/``jax.grad``).
        config: discrete choices; default: decided from the data (``aniso204`` when axial
            slices are present, else ``iso102``) with the package defaults.
        params: α, kernel widths and regularisation; default :meth:`Params.default` (with α
            estimated from the samples when they are a :class:`Samples`).
        targets: optional ``(wi, wv)`` unit vectors ``(q, 3)``: evaluate there instead of the
            81×81 UBO grid.

    Returns:
        The ABRDF table ``(81, 81, 3)`` (illumination, view, RGB), or ``(q, 3)`` at ``targets``.
    """
    meas, config, params = prepare(samples, config, params)
    return _reconstruct_jit(meas, config, params, targets)


def reconstruct_batch(
    samples: list[Samples | Measurements] | Measurements,
    config: Config | None = None,
    params: Params | None = None,
    *,
    targets=None,
) -> Float[Array, "B 81 81 3"]:
    """Reconstruct many materials in one vmapped, jit-compiled call.

    Args:
        samples: a list of measurements (all with the same slices measured) or a stacked
            :class:`Measurements` with a leading material axis.
        config, params: shared by every material (see :func:`reconstruct`).

    Returns:
        Tables of shape ``(B, 81, 81, 3)``.
    """
    if isinstance(samples, Measurements):
        meas = samples
        if config is None:
            config = Config(budget="aniso204" if meas.has_axial else "iso102")
        params = params or Params.default(config)
    else:
        items = [prepare(s, config, params) for s in samples]
        if not items:
            raise InputError("reconstruct_batch needs at least one measurement")
        meas_list = [m for m, _, _ in items]
        config = config or items[0][1]
        params = params or items[0][2]
        if any(m.has_axial != meas_list[0].has_axial for m in meas_list):
            raise InputError("a batch mixes isotropic (102) and anisotropic (204) measurements; split it")
        meas = stack_measurements(meas_list)
    return _reconstruct_batch_jit(meas, config, params, targets)


def solve_info(samples: Samples | Measurements, config: Config | None = None, params: Params | None = None) -> SolveInfo:
    """How the RBF system of a reconstruction is solved: the guard's diagnostics.

    The system depends on the measured elevation pairs, the configuration and the parameters,
    never on the sample values, so one call covers every material reconstructed with them.

    Args:
        samples, config, params: as for :func:`reconstruct`.

    Returns:
        A :class:`SolveInfo` (``reg`` used, estimated condition number, ``ok``, ``retries``:
        1 when the requested regularisation was raised, see :mod:`abrdf_jax._rbf`).
    """
    meas, config, params = prepare(samples, config, params)
    return _solve_info_jit(meas.pairs, meas.y.dtype, config, params)


@eqx.filter_jit
def _solve_info_jit(pairs, dtype, config, params):
    xc = pair_coordinates(*centre_vectors(pairs, dtype), config.parameterization)
    zeros = jnp.zeros((xc.shape[0], 1), dtype)
    return fit_rbf_info(xc, zeros, params.widths.astype(dtype), config.kernel, params.reg.astype(dtype), config.degree)[1]


def check_finite(table, where: str = "reconstruction") -> None:
    """Raise :class:`InputError` if ``table`` holds NaN or inf (never write such a table).

    Args:
        table: a reconstructed table (any shape, last axis RGB).
        where: what to name in the message (the input file).
    """
    arr = np.asarray(table)
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(
            f"{where}: the reconstruction holds {int(bad.sum())} NaN or infinite value(s) (first at "
            f"index {first}): the sample values are too large for {arr.dtype} arithmetic or the RBF solve failed; "
            "nothing was written for it (rescale the values, e.g. to a maximum near 1)"
        )


def sample(source, config: Config | None = None, params: Params | None = None, *, as_measurements: bool = False):
    """Sample the PROTOCOL slices of ``config.budget`` from a model or a dense table.

    Args:
        source: a callable ``model(wi, wv) -> (..., 3)`` (exact angles) or an ``(81, 81, 3)``
            table (interpolated over azimuth on the UBO rings).
        config: gives the budget and the elevation pairs.
        params: gives α (differentiable: the sample values follow α).
        as_measurements: return the grouped :class:`Measurements` (JAX, differentiable) instead
            of flat :class:`Samples`.
    """
    from ._slices import sample_model, sample_table

    config = config or Config()
    params = params or Params.default(config)
    if callable(source) and not hasattr(source, "shape"):
        dtype = params.alpha.dtype
        meas = sample_model(source, config.counts, params.alpha, config.pairs, dtype=dtype)
    else:
        arr = jnp.asarray(source)
        meas = sample_table(arr, config.counts, params.alpha, config.pairs, dtype=arr.dtype)
    if as_measurements:
        return meas
    return meas.to_samples(alpha_deg=params.alpha_deg)
