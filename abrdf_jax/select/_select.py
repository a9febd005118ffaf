"""Automatic model selection: the simplest reconstruction model that the measurements support.

Two stages, both on the material's own measurements (no ground truth):

1. **Isotropy** (:func:`abrdf_jax.select._isotropy.isotropy_test`): a noise-aware test on the axial
   slices. An isotropic material keeps the diagonal-only model (eq. 5, ``iso102``) and the
   anisotropic candidates are not even evaluated.
2. **Complexity** by held-out (cross-validated) error with a tolerance rule: every candidate
   configuration reconstructs the material from all samples but every ``k``-th of each slice
   (``k`` folds, each sample held out once) and predicts the held-out samples; the error is the
   RMS of ``ln(pred + ε) − ln(y + ε)`` over the held-out samples and channels (``ε`` = 1 % of the
   mean sample, as in :class:`~abrdf_jax.tuning.SelfCalibration` with ``folds="samples"``, whose
   loss this reproduces exactly; ``tests/test_select.py`` checks it). Among the candidates whose
   error is within ``tol`` (relative) of the best, the one of lowest complexity rank wins
   (the "one standard error rule" of Breiman et al., *Classification and Regression Trees*,
   1984, with a relative tolerance in place of the standard error).

**Cost.** The RBF system depends on the centres, the kernel and its parameters, never on the
values: every fold and every candidate that shares a kernel (all the subspace rules, both
budgets) is solved with *one* factorisation, the folds and candidates stacked as right-hand
sides. One compilation per kernel family and measurement shape, cached across materials
(``SelfCalibration`` would compile one reconstruction per fold and candidate).

**Complexity ranks** (:data:`CANDIDATES`): ordered first by how much of the measurement the
model uses (4 diagonal slices < 8 slices), then by the number of kernel shape parameters (the
thin-plate spline is scale free; a Gaussian has a width), then by the subspace rule (linear
``average`` < ``crossing``, which also reads the slices' crossing < the nonlinear ``log`` <
``filip2012`` with its min–max stretch); ties are broken toward the settings that won on the
MERL train split (log values before linear ones).
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._build_jit import build_jit
from .._errors import InputError
from ._choice import (  # noqa: F401
    Plan,
    Selection,
    check_budget,
    finish,
    group_configs,
    plan,
    rbf_configs,
    tolerance_choice,
    with_prior,
)
from ._candidates import (  # noqa: F401 - re-exported: the candidates' public home is select
    CANDIDATES,
    DEFAULT_ANISO,
    DEFAULT_ISO,
    KERNEL_FAMILY,
    TOL,
    Candidate,
    candidate,
)
from ._isotropy import LEVEL, MIN_EFFECT
from ._dense_held_out import dense_layout_plan, plan_errors
from .._params import Config, Params
from .._coords import pair_coordinates
from .._folds import held_out_directions, log_rms, sample_folds
from .._grid import centre_vectors
from .._pipeline import (
    _cap_centres,
    capped_samples,
    prepare,
    smoothed_samples,
    subspace_values,
)
from .._values import measurement_eps, value_space
from .._rbf import fit_rbf
from .._measurements import Measurements, Samples


# ------------------------------------------------------------------------------------------------
# Held-out error of several configurations at once


def fold_data(meas: Measurements, alpha, k: int = 4) -> dict:
    """The held-out data of ``k`` sample folds (fold ``j`` holds out samples ``j, j+k, …``).

    Args:
        meas: the grouped measurement.
        alpha: the slice offset α (radians) that places the held-out samples.
        k: number of folds (every slice keeps at least 3 samples in each fold).

    Returns:
        A pytree of arrays: ``train`` (:class:`Measurements` with a leading fold axis),
        ``test_wi``/``test_wv`` ``(k, q, 3)``, ``test_y`` ``(k, q, 3)``, ``test_mask`` ``(k, q)``
        and ``res_eps`` ``(3,)`` (the ε of the log residual, from the whole measurement).
    """
    train, tt, ty, tm = sample_folds(meas, k)
    wi, wv, eps = _fold_geometry(tt, jnp.asarray(alpha, meas.y.dtype), meas)
    return {
        "train": train,
        "test_wi": wi,
        "test_wv": wv,
        "test_y": ty.reshape(k, -1, 3),
        "test_mask": tm.reshape(k, -1),
        "res_eps": eps,
    }


@eqx.filter_jit
def _fold_geometry(test_t, alpha, meas: Measurements):
    """The held-out directions ``(k, q, 3)`` of every fold and the residual's ε: one compiled
    call per layout (op by op, a measurement's dozens of small slice operations cost more than
    its held-out fits in a batch)."""
    wis, wvs = zip(*(held_out_directions(t, meas.pairs, alpha) for t in test_t))
    dt = meas.y.dtype
    eps = measurement_eps(meas, Config().log_eps)  # 1 % of the mean, as SelfCalibration
    return jnp.stack(wis).astype(dt), jnp.stack(wvs).astype(dt), eps


def _cv_core(data: dict, configs: tuple, params: Params):
    """RMS held-out log error of every configuration of one kernel group, shape ``(G,)``."""
    train = data["train"]
    cfg0 = configs[0]
    vs = value_space(cfg0.value_space)
    # (k, 3): each fold's own ε
    eps = jax.vmap(lambda m: vs.eps(m, cfg0.log_eps))(train) if vs.is_log else None

    def fold_values(m, e):
        # what the pipeline's RBF fits (slice smoothing and spike cap: _pipeline.fit_inputs)
        enc = capped_samples(smoothed_samples(vs.encode_samples(m, e), cfg0), cfg0, vs)
        vals = _group_subspaces(enc, configs, params, lambda v: vs.encode_subspace(v, e))
        return _cap_centres(vals, m, vs)

    fit_vals = jnp.moveaxis(jax.vmap(fold_values)(train, eps), 1, 0)  # (G, k, n, C)
    pred = vs.decode(
        _fold_predictions(fit_vals, data, cfg0, params),
        None if eps is None else eps[:, None, None, :],
    )
    mask = data["test_mask"][:, :, None, None]
    return log_rms(pred, data["test_y"][:, :, None, :], data["res_eps"], mask, axis=(0, 1, 3))


def _group_subspaces(m: Measurements, configs: tuple, params: Params, encode=None):
    """Subspace values ``(G, n, C)`` of every configuration of one kernel group (``encode``d
    for the RBF): one set of slice interpolations when they differ in the rule only."""
    encode = encode or (lambda v: v)
    if len({c.interp for c in configs}) == 1:
        rules = tuple(c.subspace_rule for c in configs)
        return encode(subspace_values(m, configs[0], params, rules=rules))
    return jnp.stack([encode(subspace_values(m, c, params)) for c in configs])


def _fold_predictions(fit_vals, data: dict, cfg0: Config, params: Params):
    """The RBF part of the held-out fits, linear in the values it fits: fold ``j``'s prediction
    at fold ``j``'s held-out samples ``(k, q, G, C)`` from the centre values ``fit_vals``
    ``(G, k, n, C)`` of every configuration and fold (in the RBF's value space)."""
    G, k, n, C = fit_vals.shape
    # Every fold and configuration as right-hand sides of one system (it ignores the values).
    out = _rbf_at_held_out(jnp.moveaxis(fit_vals, 2, 0).reshape(n, G * k * C), data, cfg0, params)
    fold = jnp.arange(k)
    return out.reshape(k, -1, G, k, C)[fold, :, :, fold, :]  # fold j's own: (k, q, G, C)


def _rbf_at_held_out(rhs, data: dict, cfg0: Config, params: Params):
    """The RBF fitted at the centres to the columns ``rhs`` ``(n, R)``, read at every fold's
    held-out samples: ``(k, q, R)`` (the centres, and so the system, are the same in every fold)."""
    train = data["train"]
    dtype = train.y.dtype
    wi_c, wv_c = centre_vectors(train.pairs, dtype, train.centre_azimuths)
    xc = pair_coordinates(wi_c, wv_c, cfg0.parameterization)
    rbf = fit_rbf(
        xc, rhs, params.widths.astype(dtype), cfg0.kernel, params.reg.astype(dtype), cfg0.degree
    )
    k, q = data["test_wi"].shape[:2]
    xq = pair_coordinates(
        data["test_wi"].reshape(-1, 3), data["test_wv"].reshape(-1, 3), cfg0.parameterization
    )
    return rbf(xq).reshape(k, q, -1)


@build_jit
def held_out_terms(data: dict, config: Config, params: Params, centres: tuple[int, ...]):
    """The held-out fits of :func:`_cv_core` as matrices, for rules affine in the slice terms
    (:mod:`abrdf_jax._rules`) in a value space without a log after the rule (the JAX-free
    held-out errors, :mod:`abrdf_jax.select._held_out_entry`).

    Returns ``(terms, ones)``: ``terms`` ``(k, P, 3, q, S·nmax)``, the RBF prediction at fold
    ``j``'s held-out samples from pair ``p``'s slice term ``a``, ``b`` or ``c`` alone, as a
    matrix on the values of fold ``j``'s training slots (``s · nmax + i`` of ``data["train"]``);
    ``ones`` ``(k, P, q)``, the prediction from the constant 1 at pair ``p``'s centres.
    ``centres``: the number of RBF centres of each pair (``abrdf_jax._grid.centre_layout``).
    Built as the reconstruction operator is (``abrdf_jax._operator``): the pipeline's own
    linear parts applied to unit vectors."""
    train = data["train"]
    dtype = train.y.dtype
    k, s, nmax = train.t.shape
    unit = jnp.eye(s * nmax, dtype=dtype).reshape(s, nmax, s * nmax)
    terms = jax.vmap(lambda m: subspace_values(m.replace(y=unit), config, params, terms=True))(
        train
    )  # (k, 3, n, slots)
    n = terms.shape[2]
    rbf = _rbf_at_held_out(jnp.eye(n, dtype=dtype), data, config, params)  # (k, q, n)
    bounds = np.cumsum((0,) + tuple(centres))
    maps, ones = [], []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        maps.append(jnp.einsum("kqn,ktns->ktqs", rbf[..., lo:hi], terms[:, :, lo:hi]))
        ones.append(jnp.sum(rbf[..., lo:hi], axis=-1))
    return jnp.stack(maps, 1), jnp.stack(ones, 1)


_cv_jit = eqx.filter_jit(_cv_core)


@eqx.filter_jit
def held_out_errors_batch(data, configs: tuple, params: Params):
    """Held-out RMS log errors ``(B, G)`` of the configurations ``configs`` (one RBF group, see
    :func:`group_configs`) for a batch of materials: ``data`` is :func:`fold_data` of each,
    stacked along a leading axis (one layout); one compiled program for the whole batch."""
    return jax.vmap(lambda d: _cv_core(d, configs, params))(data)


def held_out_errors(
    samples: Samples | Measurements,
    configs: dict[str, Config],
    *,
    alpha_deg: float | None = None,
    k: int = 4,
    dtype=None,
) -> dict[str, float]:
    """Held-out RMS log error of each named configuration on one material's own samples.

    Args:
        samples: the measurement (:class:`Samples` are grouped, α estimated unless given).
        configs: ``{name: Config}``; every one must fit the measurement (``aniso204`` needs axial
            slices). Each uses :meth:`Params.default` with the measurement's α.
        alpha_deg: slice offset for :class:`Samples`; for :class:`Measurements` default 15°.
        k: number of sample folds.

    Returns:
        ``{name: error}`` (log units, scale free; lower is better).
    """
    meas, alpha = _grouped(samples, alpha_deg, dtype)
    out = {}
    data = fold_data(meas, np.deg2rad(alpha), k)
    for names, cfgs in group_configs(configs):
        for c in cfgs:
            if c.budget == "aniso204" and not meas.has_axial:
                raise InputError(f"model {c} needs axial slices, but the measurement has none")
        params = Params.default(cfgs[0], alpha_deg=alpha, dtype=meas.y.dtype)
        errs = np.asarray(_cv_jit(data, cfgs, params))
        out.update({n: float(e) for n, e in zip(names, errs)})
    return out


def _grouped(samples, alpha_deg, dtype=None) -> tuple[Measurements, float]:
    if hasattr(samples, "to_measurements"):  # the command line's numpy slices
        samples = samples.to_measurements()
    if isinstance(samples, Measurements):
        return samples, (15.0 if alpha_deg is None else float(alpha_deg))
    if not isinstance(samples, Samples):
        raise InputError(f"samples must be Samples or Measurements, got {type(samples).__name__}")
    params = None if alpha_deg is None else Params.default(Config(), alpha_deg=alpha_deg)
    meas, _, p = prepare(samples, None, params, dtype=dtype)
    return meas, p.alpha_deg


def select_model(
    samples: Samples | Measurements,
    *,
    candidates: tuple[str, ...] | str = "auto",
    budget: str | None = None,
    tol: float = TOL,
    k: int = 4,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    alpha_deg: float | None = None,
    dtype=None,
    prior=None,
    fused=True,
) -> Selection:
    """Choose the simplest reconstruction model the measurements support.

    Args:
        samples: one material's measurement.
        candidates: ``"auto"`` (the isotropy test, then :data:`DEFAULT_ANISO` when the
            material is anisotropic), ``"kernels"`` (also the kernel families of
            :data:`KERNEL_FAMILY`: one compilation each), or a tuple of candidate names. On a
            dense capture (``centre_azimuths`` set) the held-out errors of candidates affine in
            the slice terms are computed in numpy in float64 whatever ``dtype``
            (:mod:`abrdf_jax.select._dense_held_out`: the float32 solve on its 2,304 centres is
            several per cent off), as the command line computes them.
        budget: force ``"iso102"`` or ``"aniso204"`` (no isotropy decision; candidates of other
            budgets are dropped).
        tol: relative tolerance of the rule (module docstring).
        k: number of sample folds.
        noise: relative noise of one sample, if known (else estimated; see the isotropy test).
        level, min_effect: thresholds of the isotropy test.
        alpha_deg: slice offset (default: estimated from :class:`Samples`, 15° for
            :class:`Measurements`).
        prior: a :class:`abrdf_jax.prior.Prior`: the prior-only model joins the candidates
            (rank above every RBF model; :func:`abrdf_jax.select._choice.with_prior`), scored
            on the same folds (:mod:`abrdf_jax.select._prior`). Chosen, the selection's name is
            ``"prior"`` and its ``config`` says the budget whose slices it reads.
        fused: with a prior, the fused model (prior + kernel on the residual) joins too, rank
            above the prior: ``True`` at the prior's own fixed hyper-parameters (its file's, else
            the package's defaults), a :class:`abrdf_jax.prior.FusedHyper`, or ``False``
            (not a candidate). Scored on the same folds (:mod:`abrdf_jax.select._fused`).

    Returns:
        A :class:`Selection`.
    """
    t0 = time.perf_counter()
    plan = _plan(samples, candidates, budget, noise, level, min_effect, alpha_deg, dtype)
    from ._fused import fused_of

    fh = fused_of(prior, fused)
    if prior is not None:
        plan = with_prior(plan, fh is not None)
    errors = None
    if len(plan.configs) > 1:
        if dense_layout_plan(plan):  # numpy, float64 (select._dense_held_out): None if singular
            (errors,) = plan_errors([plan], k)
        if errors is None:
            rbf = rbf_configs(plan.configs)
            errors = held_out_errors(plan.meas, rbf, alpha_deg=plan.alpha, k=k)
        if prior is not None:
            from ._prior import prior_held_out_error

            b = plan.configs["prior"].budget
            a = np.deg2rad(plan.alpha)
            errors["prior"] = prior_held_out_error(plan.meas, prior, a, k, b)
            if fh is not None:
                from ._fused import fused_held_out_error

                errors["fused"] = fused_held_out_error(plan.meas, prior, a, k, b, fh)
    return _finish(plan, errors, tol, k, time.perf_counter() - t0)


def _plan(samples, candidates, budget, noise, level, min_effect, alpha_deg, dtype) -> Plan:
    """Group, test isotropy and list the candidates left (everything before the folds)."""
    check_budget(budget)
    meas, alpha = _grouped(samples, alpha_deg, dtype)
    return plan(meas, alpha, candidates, budget, noise, level, min_effect)


def _params(config, alpha_deg, dtype) -> Params:
    return Params.default(config, alpha_deg=alpha_deg, dtype=dtype)


def _finish(p: Plan, errors: dict | None, tol: float, k: int, seconds: float) -> Selection:
    """The tolerance rule on the held-out errors (``None``: a single candidate)."""
    return finish(p, errors, tol, k, seconds, _params)
