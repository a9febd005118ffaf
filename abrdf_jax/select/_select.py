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

import dataclasses
import math
import time
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._names import MODEL_TOL
from ._isotropy import LEVEL, MIN_EFFECT, IsotropyReport, isotropy_test
from .._params import Config, Params
from .._coords import pair_coordinates
from .._folds import held_out_directions, log_rms, sample_folds
from .._grid import centre_vectors
from .._pipeline import prepare, subspace_values
from .._values import measurement_eps, value_space
from .._rbf import fit_rbf
from .._measurements import Measurements, Samples


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A named model: its configuration (budget ``iso102``/``aniso204`` and settings) and rank."""

    name: str
    settings: dict
    rank: int
    description: str

    def config(self, **overrides) -> Config:
        """The :class:`Config` of this candidate (``overrides``: e.g. ``pairs``)."""
        return Config(**{**self.settings, **overrides})


def _rec(budget, **kw):
    from .._params import RECOMMENDED

    return dict(budget=budget, **{**RECOMMENDED, **kw})


# name -> settings, in complexity order (see the module docstring)
_SETTINGS = {
    "iso": _rec("iso102"),
    "iso-linear": _rec("iso102", value_space="linear"),
    "iso-gaussian": _rec("iso102", kernel="gaussian", degree=0),
    "paper": dict(budget="iso102"),
    "aniso-average": _rec("aniso204", rule="average"),
    "aniso-crossing": _rec("aniso204", rule="crossing"),
    # The multiplicative rule on the samples, log after: in the log of the samples (the
    # recommended value space) it would multiply logs; there "crossing" is its counterpart.
    "aniso-log": _rec("aniso204", rule="log", value_space="log"),
    "aniso": _rec("aniso204"),
    "paper-aniso": dict(budget="aniso204"),
}
_DESCRIPTIONS = {
    "iso": "diagonal slices only (eq. 5); thin-plate spline on the log of the samples (recommended)",
    "iso-linear": "diagonal slices only; thin-plate spline on linear values",
    "iso-gaussian": "diagonal slices only; Gaussian kernel (a width) on log values",
    "paper": "Filip 2012 as published, isotropic: Gaussian kernel on linear values",
    "aniso-average": "all 8 slices, mean of the two slices (linear rule)",
    "aniso-crossing": "all 8 slices, sum less the crossing value (reproduces both slices)",
    "aniso-log": "all 8 slices, multiplicative rule (product over the crossing), log after it",
    "aniso": "all 8 slices, eq. (2-4) min-max stretch (filip2012); the recommended anisotropic model",
    "paper-aniso": "Filip 2012 as published, anisotropic: eq. (2-4), Gaussian on linear values",
}
#: The named models, in complexity order (rank = position; see the module docstring).
CANDIDATES: dict[str, Candidate] = {
    name: Candidate(name, settings, rank, _DESCRIPTIONS[name])
    for rank, (name, settings) in enumerate(_SETTINGS.items())
}
#: Candidates tried by default: the budget and the subspace rule (one RBF factorisation).
DEFAULT_ISO = ("iso",)
#: ("aniso-log" is not among them: in the log of the samples "aniso-crossing" is the
#: multiplicative rule, and its own value space would be one more RBF factorisation.)
DEFAULT_ANISO = ("iso", "aniso-average", "aniso-crossing", "aniso")
#: Optional kernel-family candidates (each family is one more compilation).
KERNEL_FAMILY = ("iso", "iso-linear", "iso-gaussian")
TOL = MODEL_TOL


def candidate(name: str) -> Candidate:
    """A named candidate; :class:`InputError` listing the names otherwise."""
    if name not in CANDIDATES:
        raise InputError(f"unknown model {name!r}; choose auto or one of: {', '.join(CANDIDATES)}")
    return CANDIDATES[name]


# ------------------------------------------------------------------------------------------------
# Held-out error of several configurations at once


def _group_key(config: Config):
    """Configurations with equal keys share the RBF system (and the default parameters)."""
    fields = ("kernel", "degree", "value_space", "parameterization", "log_eps")
    return tuple(getattr(config, f) for f in fields)


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
    a = jnp.asarray(alpha, meas.y.dtype)
    wis, wvs = zip(*(held_out_directions(tt[j], meas.pairs, a) for j in range(k)))
    return {
        "train": train,
        "test_wi": jnp.stack(wis).astype(meas.y.dtype),
        "test_wv": jnp.stack(wvs).astype(meas.y.dtype),
        "test_y": ty.reshape(k, -1, 3),
        "test_mask": tm.reshape(k, -1),
        "res_eps": measurement_eps(meas, Config().log_eps),  # 1 % of the mean, as SelfCalibration
    }


def _cv_core(data: dict, configs: tuple, params: Params):
    """RMS held-out log error of every configuration of one kernel group, shape ``(G,)``."""
    train = data["train"]
    cfg0 = configs[0]
    vs = value_space(cfg0.value_space)
    dtype = train.y.dtype
    # (k, 3): each fold's own ε
    eps = jax.vmap(lambda m: vs.eps(m, cfg0.log_eps))(train) if vs.is_log else None

    def fold_values(m, e, c):
        return vs.encode_subspace(subspace_values(vs.encode_samples(m, e), c, params), e)

    fit_vals = jnp.stack(
        [jax.vmap(lambda m, e, c=c: fold_values(m, e, c))(train, eps) for c in configs]
    )
    G, k, n, C = fit_vals.shape
    # Every fold and configuration as right-hand sides of one system (it ignores the values).
    rhs = jnp.moveaxis(fit_vals, 2, 0).reshape(n, G * k * C)
    wi_c, wv_c = centre_vectors(train.pairs, dtype, train.centre_azimuths)
    xc = pair_coordinates(wi_c, wv_c, cfg0.parameterization)
    rbf = fit_rbf(
        xc, rhs, params.widths.astype(dtype), cfg0.kernel, params.reg.astype(dtype), cfg0.degree
    )
    q = data["test_wi"].shape[1]
    xq = pair_coordinates(
        data["test_wi"].reshape(-1, 3), data["test_wv"].reshape(-1, 3), cfg0.parameterization
    )
    out = rbf(xq).reshape(k, q, G, k, C)
    fold = jnp.arange(k)
    # fold j's own prediction at fold j's held-out samples: (k, q, G, C)
    out = out[fold, :, :, fold, :]
    pred = vs.decode(out, None if eps is None else eps[:, None, None, :])
    mask = data["test_mask"][:, :, None, None]
    return log_rms(pred, data["test_y"][:, :, None, :], data["res_eps"], mask, axis=(0, 1, 3))


_cv_jit = eqx.filter_jit(_cv_core)


@eqx.filter_jit
def held_out_errors_batch(data, configs: tuple, params: Params):
    """Held-out RMS log errors ``(B, G)`` of the configurations ``configs`` (one RBF group, see
    :func:`group_configs`) for a batch of materials: ``data`` is :func:`fold_data` of each,
    stacked along a leading axis (one layout); one compiled program for the whole batch."""
    return jax.vmap(lambda d: _cv_core(d, configs, params))(data)


def group_configs(configs: dict[str, Config]) -> list[tuple[tuple[str, ...], tuple[Config, ...]]]:
    """Split named configurations into groups that share one RBF system."""
    groups: dict = {}
    for name, cfg in configs.items():
        groups.setdefault(_group_key(cfg), []).append((name, cfg))
    return [(tuple(n for n, _ in g), tuple(c for _, c in g)) for g in groups.values()]


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
    if isinstance(samples, Measurements):
        return samples, (15.0 if alpha_deg is None else float(alpha_deg))
    if not isinstance(samples, Samples):
        raise InputError(f"samples must be Samples or Measurements, got {type(samples).__name__}")
    params = None if alpha_deg is None else Params.default(Config(), alpha_deg=alpha_deg)
    meas, _, p = prepare(samples, None, params, dtype=dtype)
    return meas, p.alpha_deg


# ------------------------------------------------------------------------------------------------
# The tolerance rule and the selection


def tolerance_choice(
    errors: dict[str, float], ranks: dict[str, int], tol: float = TOL
) -> tuple[str, str]:
    """The simplest candidate whose error is within ``tol`` (relative) of the best.

    Args:
        errors: ``{name: held-out error}`` (non-finite errors never win).
        ranks: ``{name: complexity rank}`` (lower is simpler; ties go to the lower error).
        tol: relative tolerance, e.g. 0.05 for 5 %.

    Returns:
        ``(name, reason)``.

    Raises:
        InputError: no finite error, or a negative tolerance.
    """
    if not (tol >= 0 and math.isfinite(tol)):
        raise InputError(f"tol must be a finite fraction >= 0, got {tol!r}")
    finite = {n: e for n, e in errors.items() if math.isfinite(e)}
    if not finite:
        raise InputError(f"no candidate has a finite held-out error: {errors}")
    best = min(finite, key=lambda n: (finite[n], ranks[n]))
    bound = finite[best] * (1.0 + tol)
    within = [n for n in finite if finite[n] <= bound]
    pick = min(within, key=lambda n: (ranks[n], finite[n]))
    if pick == best:
        reason = f"{pick} has the lowest held-out error ({finite[pick]:.4g})"
        simpler = [n for n in finite if ranks[n] < ranks[pick]]
        if simpler:
            s = min(simpler, key=lambda n: finite[n])
            reason += f"; the best simpler model, {s}, is {100 * (finite[s] / finite[pick] - 1):.1f}% worse (> {100 * tol:g}%)"
    else:
        reason = (
            f"{pick} is the simplest model within {100 * tol:g}% of the best held-out error "
            f"({finite[pick]:.4g} vs {finite[best]:.4g} of {best})"
        )
    return pick, reason


@dataclasses.dataclass(frozen=True)
class Selection:
    """What :func:`select_model` decided, and the evidence.

    Attributes:
        name: the chosen candidate's name (see :data:`CANDIDATES`).
        config: its :class:`Config`; params: its :class:`Params` (α of the measurement).
        errors: ``{name: held-out RMS log error}`` of the candidates tried.
        ranks: ``{name: complexity rank}`` of those candidates.
        isotropy: the :class:`IsotropyReport` (``None`` if the budget was forced).
        reason: why this model (one or two sentences).
        tol: the tolerance used; k: the number of folds; seconds: wall time of the selection.
    """

    name: str
    config: Config
    params: Params
    errors: dict
    ranks: dict
    isotropy: IsotropyReport | None
    reason: str
    tol: float
    k: int
    seconds: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready summary (what ``abrdf-jax reconstruct`` saves as ``OUT.model.json``)."""
        from ..io._paramfile import params_to_dict

        p = params_to_dict(self.config, self.params)
        return {
            "format": "abrdf_jax.model/1",
            "model": self.name,
            "config": p["config"],
            "params": p["params"],
            "reason": self.reason,
            "tol": self.tol,
            "folds": self.k,
            "candidates": [
                {
                    "name": n,
                    "held_out_log_rms": _finite(self.errors[n]),
                    "rank": self.ranks[n],
                    "description": CANDIDATES[n].description if n in CANDIDATES else "",
                }
                for n in sorted(self.errors, key=lambda n: self.ranks[n])
            ],
            "isotropy": None if self.isotropy is None else self.isotropy.to_dict(),
            "seconds": self.seconds,
        }


def _finite(x):
    return float(x) if math.isfinite(x) else None


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
) -> Selection:
    """Choose the simplest reconstruction model the measurements support.

    Args:
        samples: one material's measurement.
        candidates: ``"auto"`` (the isotropy test, then :data:`DEFAULT_ANISO` when the
            material is anisotropic), ``"kernels"`` (also the kernel families of
            :data:`KERNEL_FAMILY`: one compilation each), or a tuple of candidate names.
        budget: force ``"iso102"`` or ``"aniso204"`` (no isotropy decision; candidates of other
            budgets are dropped).
        tol: relative tolerance of the rule (module docstring).
        k: number of sample folds.
        noise: relative noise of one sample, if known (else estimated; see the isotropy test).
        level, min_effect: thresholds of the isotropy test.
        alpha_deg: slice offset (default: estimated from :class:`Samples`, 15° for
            :class:`Measurements`).

    Returns:
        A :class:`Selection`.
    """
    t0 = time.perf_counter()
    plan = _plan(samples, candidates, budget, noise, level, min_effect, alpha_deg, dtype)
    errors = None
    if len(plan.configs) > 1:
        errors = held_out_errors(plan.meas, plan.configs, alpha_deg=plan.alpha, k=k)
    return _finish(plan, errors, tol, k, time.perf_counter() - t0)


class _Plan(NamedTuple):
    """A measurement's selection before the held-out errors: its candidates and the evidence."""

    meas: Measurements
    alpha: float
    budget: str | None
    report: IsotropyReport | None
    configs: dict
    ranks: dict


def _plan(samples, candidates, budget, noise, level, min_effect, alpha_deg, dtype) -> _Plan:
    """Group, test isotropy and list the candidates left (everything before the folds)."""
    if budget not in (None, "iso102", "aniso204"):
        raise InputError(f"budget must be 'iso102', 'aniso204' or None, got {budget!r}")
    meas, alpha = _grouped(samples, alpha_deg, dtype)
    if budget == "aniso204" and not meas.has_axial:
        raise InputError("budget 'aniso204' needs axial slices, but the measurement has none")
    report = None
    if budget is None:
        report = isotropy_test(meas, noise=noise, level=level, min_effect=min_effect)
        aniso_ok = not report.isotropic
    else:
        aniso_ok = budget == "aniso204"
    if candidates in ("auto", "kernels"):
        names = list(DEFAULT_ANISO if aniso_ok else DEFAULT_ISO)
        if candidates == "kernels":
            names += [n for n in KERNEL_FAMILY if n not in names]
    else:
        names = [candidate(n).name for n in candidates]
        if not names:
            raise InputError("candidates: give at least one model name")
    if budget == "aniso204":
        names = [n for n in names if CANDIDATES[n].settings["budget"] == "aniso204"] or ["aniso"]
    elif budget == "iso102" or not aniso_ok:
        names = [n for n in names if CANDIDATES[n].settings["budget"] == "iso102"] or ["iso"]
    configs = {n: CANDIDATES[n].config(pairs=meas.pairs) for n in names}
    ranks = {n: CANDIDATES[n].rank for n in names}
    return _Plan(meas, alpha, budget, report, configs, ranks)


def _finish(plan: _Plan, errors: dict | None, tol: float, k: int, seconds: float) -> Selection:
    """The tolerance rule on the held-out errors (``None``: a single candidate)."""
    names = list(plan.configs)
    if errors is None:
        errors = {names[0]: float("nan")}
        pick = names[0]
        reason = f"{pick}: the only candidate left"
    else:
        pick, reason = tolerance_choice(errors, plan.ranks, tol)
    if plan.report is not None:
        reason = f"{plan.report.reason}. {reason}"
    elif plan.budget is not None:
        reason = f"budget forced to {plan.budget}. {reason}"
    config = plan.configs[pick]
    params = Params.default(config, alpha_deg=plan.alpha, dtype=plan.meas.y.dtype)
    return Selection(pick, config, params, errors, plan.ranks, plan.report, reason, tol, k, seconds)
