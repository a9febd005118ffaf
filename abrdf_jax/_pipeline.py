"""The reconstruction pipeline: measurements → slices → toroidal subspaces → RBF → ABRDF table.

``reconstruct`` is a pure function of a :class:`Measurements` pytree (the sample values and their
slice positions), a static :class:`Config` and traced :class:`Params` (α, kernel widths,
regularisation): it is jit-compiled once per configuration and shape, differentiable in the
parameters and the values, and vmaps over materials (``reconstruct_batch``), where the RBF
factorisation is shared because it depends on the parameters only.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._coords import pair_coordinates
from ._errors import InputError
from ._finite import when_traced
from ._grid import centre_count, centre_vectors, keep_centres, ubo_target_vectors
from ._grouping import group_slices
from ._measurements import Measurements, Samples, stack_measurements
from ._params import Config, Params
from ._rbf import SolveInfo, fit_rbf_info
from ._slices import PROTOCOL_PAIRS
from ._smoothing import smooth_slices, smooths_slices
from ._spikes import cap_samples
from ._subspace import centre_subspaces
from ._values import value_space


def subspace_values(
    meas: Measurements,
    config: Config,
    params: Params,
    rules: tuple[str, ...] | None = None,
    terms: bool = False,
) -> Float[Array, "n 3"]:
    """Values of the reconstructed toroidal subspaces at the RBF centres (eq. 2–5).

    ``rules``: several subspace rules at once, ``(R, n, 3)``, from one set of slice
    interpolations (default: ``config``'s rule alone, ``(n, 3)``). ``terms``: instead, the
    slice terms ``(a, b, c)`` that the rules combine, ``(3, n, 3)``
    (:func:`abrdf_jax._subspace.subspace_terms`)."""
    rule = config.subspace_rule if rules is None else tuple(rules)
    return centre_subspaces(
        meas.t, meas.y, meas.count, meas.pairs, meas.centre_azimuths,
        params.alpha.astype(meas.y.dtype), rule, config.interp, terms,
    )  # fmt: skip


def _fit_centres(vals, pairs, config: Config, params: Params, guard: bool = True, azimuths=None):
    """The RBF fit at the centres of ``pairs`` (one place builds the system): ``(interpolant, info)``."""
    p = params.astype(vals.dtype)
    xc = pair_coordinates(*centre_vectors(pairs, vals.dtype, azimuths), config.parameterization)
    return fit_rbf_info(xc, vals, p.widths, config.kernel, p.reg, config.degree, guard=guard)


def rbf_map(
    fit_vals: Float[Array, "n C"],
    pairs,
    config: Config,
    params: Params,
    targets=None,
    keep: bool = True,
    guard: bool = True,
    azimuths: int | None = None,
):
    """RBF fit at the centres of ``pairs`` and evaluation at the targets: linear in ``fit_vals``.

    Args:
        fit_vals: values at the RBF centres (``centre_layout(pairs)`` order), any number of columns.
        targets: ``(wi, wv)`` or ``None`` for the 6561 UBO pairs (then ``keep`` puts ``fit_vals``
            back at the centres' grid pairs).
        azimuths: the centre layout's ``centre_azimuths`` (``Measurements.centre_azimuths``).

    Returns:
        ``(q, C)`` values in the fit space (before any exp).
    """
    dtype = fit_vals.dtype
    rbf = _fit_centres(fit_vals, pairs, config, params, guard, azimuths)[0]
    wi_t, wv_t = ubo_target_vectors(dtype) if targets is None else targets
    out = rbf(pair_coordinates(wi_t, wv_t, config.parameterization))
    if targets is None and keep:
        out = keep_centres(out, fit_vals, pairs, azimuths)
    return out


#: A dense capture's RBF input in the value space ``"log"`` (log after the subspace rule) is
#: capped at this quantile of the centre values plus this margin (log units, i.e. x 1.65): see
#: :func:`_cap_centres`. The log-sample value space caps the samples instead (``_spikes.py``).
CENTRE_QUANTILE, CENTRE_MARGIN = 0.95, 0.5


def _cap_centres(fit_vals, meas: Measurements, vs):
    """A dense capture (``meas.centre_azimuths`` set) resolves specular spikes that 26 samples per
    slice alias. Put back at their grid pairs they are kept, but the global kernel would carry a
    spike across elevations to pairs it never saw. In the value space ``"log"`` (which takes the
    log after the subspace rule, so the samples cannot be capped first) the RBF fits log values
    capped at ``CENTRE_QUANTILE`` of the centre values + ``CENTRE_MARGIN``; the restored values
    themselves go back unchanged. Sparse captures there, and linear value spaces, are not touched;
    the log-sample value space caps its samples in every layout (:mod:`abrdf_jax._spikes`)."""
    if meas.centre_azimuths is None or not vs.log_subspace:
        return fit_vals
    return cap_samples(fit_vals, (CENTRE_QUANTILE, CENTRE_MARGIN))  # over the centres (axis -2)


def capped_samples(enc: Measurements, config: Config, vs) -> Measurements:
    """The encoded samples the RBF's subspaces are restored from: spike-capped in the log-sample
    value space (``config.spike_cap``, :mod:`abrdf_jax._spikes`), else as they are."""
    if not (vs.log_samples and config.spike_cap):
        return enc
    return enc.replace(y=cap_samples(enc.y, config.spike_cap, enc.mask))


def smoothed_samples(enc: Measurements, config: Config) -> Measurements:
    """The encoded samples after the slice smoothing (``config.slice_smoothing``,
    :mod:`abrdf_jax._smoothing`) in the log-sample value space, else as they are."""
    if not smooths_slices(config):
        return enc
    z = smooth_slices(config.slice_smoothing, enc.y, enc.t, enc.count)[0]
    return enc.replace(y=z)


def fit_inputs(meas: Measurements, config: Config, params: Params, vs, eps):
    """``(values, restored, fitted)``: the subspace values at the centres as the rule gives them,
    in the RBF's value space as restored from the (smoothed: :mod:`abrdf_jax._smoothing`)
    samples (what goes back at the grid pairs), and as the RBF fits them (from spike-capped log
    samples, or capped centre values: :mod:`abrdf_jax._spikes`)."""
    enc = smoothed_samples(vs.encode_samples(meas, eps), config)
    vals = subspace_values(enc, config, params)
    raw = vs.encode_subspace(vals, eps)
    if vs.log_samples:
        return vals, raw, subspace_values(capped_samples(enc, config, vs), config, params)
    return vals, raw, _cap_centres(raw, meas, vs)


def _reconstruct_core(
    meas: Measurements, config: Config, params: Params, targets=None, guard: bool = True
):
    vs = value_space(config.value_space)
    eps = vs.eps(meas, config.log_eps)
    vals, fit_raw, fit_vals = fit_inputs(meas, config, params, vs, eps)
    # The restored subspaces are put back at their grid pairs (the paper's step 3) in the RBF's
    # value space, except after a log of the subspace values: there the values themselves go back
    # (exp(ln(x + ε)) − ε would only round them).
    keep_after = vs.log_subspace and targets is None
    az = meas.centre_azimuths
    out = rbf_map(fit_vals, meas.pairs, config, params, targets, False, guard, az)
    if targets is None and not keep_after:
        out = keep_centres(out, fit_raw, meas.pairs, az)
    out = vs.decode(out, eps)
    if keep_after:
        out = keep_centres(out, jnp.maximum(vals, 0.0), meas.pairs, az)
    if targets is None:
        out = out.reshape(81, 81, out.shape[-1])
    return out


_reconstruct_jit = eqx.filter_jit(_reconstruct_core)


@eqx.filter_jit
def _reconstruct_batch_jit(meas, config, params, targets=None, guard=True):
    return jax.vmap(lambda m: _reconstruct_core(m, config, params, targets, guard))(meas)


def infer_budget(samples: Samples | Measurements, alpha_deg: float | None = None) -> str:
    """``"aniso204"`` when axial slices were measured, else ``"iso102"``."""
    if isinstance(samples, Samples):
        samples, _ = group_slices(samples, alpha_deg)
    return "aniso204" if samples.has_axial else "iso102"


def prepare(
    samples: Samples | Measurements, config: Config | None, params: Params | None, dtype=None
):
    """Group samples into slices and resolve the defaults of ``config`` and ``params``."""
    if isinstance(samples, Samples):
        alpha = None if params is None else params.alpha_deg
        # Config's default pairs are the protocol's: then the capture's own pairs are inferred
        # (a device's elevations, extra pairs); pairs named in a Config are grouped on as given.
        pairs = None if config is None else config.pairs
        pairs = None if pairs is not None and tuple(map(tuple, pairs)) == PROTOCOL_PAIRS else pairs
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
        raise InputError(
            "Config(budget='aniso204') needs axial slices, but the measurement has none; use budget='iso102'"
        )
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

    Raises:
        InputError: NaN or infinite sample values (when they are concrete; inside a ``jit`` the
            compiled call raises a ``RuntimeError`` with the same message, :mod:`abrdf_jax._finite`).
    """
    meas, config, params = prepare(samples, config, params)
    return _reconstruct_jit(_finite_when_traced(meas), config, params, targets)


def reconstruct_batch(
    samples: list[Samples | Measurements] | Measurements,
    config: Config | None = None,
    params: Params | None = None,
    *,
    targets=None,
    guard: bool = True,
) -> Float[Array, "B 81 81 3"]:
    """Reconstruct many materials in one vmapped, jit-compiled call.

    Args:
        samples: a list of measurements (all with the same slices measured) or a stacked
            :class:`Measurements` with a leading material axis.
        config, params: shared by every material (see :func:`reconstruct`).
        guard: ``False`` solves the RBF system exactly as asked, without raising λ where it is
            singular to working precision (:mod:`abrdf_jax._rbf`, "Guard"; for the stability benchmark).

    Returns:
        Tables of shape ``(B, 81, 81, 3)``.

    Raises:
        InputError: as :func:`reconstruct` (non-finite samples: at once, or at run time in a jit).
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
            raise InputError(
                "a batch mixes isotropic (102) and anisotropic (204) measurements; split it"
            )
        meas = stack_measurements(meas_list)
    return _reconstruct_batch_jit(_finite_when_traced(meas), config, params, targets, guard)


def _finite_when_traced(meas: Measurements) -> Measurements:
    """``meas`` whose ``t`` and ``y`` carry a run-time finiteness check when they are traced (a
    user's ``jit``): a NaN sample raises instead of spreading over the table. Concrete values
    were checked when the :class:`Measurements` was made."""
    if not isinstance(meas.y, jax.core.Tracer) and not isinstance(meas.t, jax.core.Tracer):
        return meas  # (replace() would run the concrete checks once more)
    return meas.replace(
        t=when_traced(meas.t, "Measurements.t"), y=when_traced(meas.y, "Measurements.y")
    )


def solve_info(
    samples: Samples | Measurements, config: Config | None = None, params: Params | None = None
) -> SolveInfo:
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
    return _solve_info_jit(meas.pairs, meas.y.dtype, config, params, meas.centre_azimuths)


@eqx.filter_jit
def _solve_info_jit(pairs, dtype, config, params, azimuths=None):
    n = centre_count(pairs, azimuths)
    return _fit_centres(jnp.zeros((n, 1), dtype), pairs, config, params, True, azimuths)[1]
