"""The automatic model choice without the numerics (no JAX): candidates, the rule, the record.

:func:`plan` is everything of :func:`abrdf_jax.select.select_model` before the held-out errors
(the isotropy test and the candidates left), :func:`tolerance_choice` the rule after them and
:func:`finish` the :class:`Selection`; the held-out errors themselves are JAX
(:mod:`abrdf_jax.select._select`). A measurement left with one candidate is chosen here
entirely (:func:`quick_selection`): the command line does so without importing JAX.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import numpy as np

from .._config import Config, default_values
from .._errors import InputError
from .._memo import BoundedMemo
from ._candidates import (
    BIVARIATE,
    BIVARIATE_RANK,
    CANDIDATES,
    DEFAULT_ANISO,
    DEFAULT_ISO,
    FUSED,
    KERNEL_FAMILY,
    LEARNED,
    PRIOR,
    TOL,
    candidate,
    description,
)
from ._isotropy import LEVEL, MIN_EFFECT, IsotropyReport, isotropy_test


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
        config: its :class:`Config`; params: its :class:`Params` (α of the measurement). For
            the bivariate model (not an RBF) ``config`` carries only the budget, the slices it
            reads: reconstruct with :meth:`reconstruct`, not ``abrdf_jax.reconstruct(...,
            config, params)``, which would run the RBF of that config.
        errors: ``{name: held-out RMS log error}`` of the candidates tried.
        ranks: ``{name: complexity rank}`` of those candidates.
        isotropy: the :class:`IsotropyReport` (``None`` if the budget was forced).
        reason: why this model (one or two sentences).
        tol: the tolerance used; k: the number of folds; seconds: wall time of the selection.
    """

    name: str
    config: object  # Config
    params: object  # Params (select_model), or their numpy values (quick_selection)
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
            **self.evidence(),
            "seconds": self.seconds,
        }

    def reconstruct(self, samples):
        """The chosen model's ``(81, 81, 3)`` table of ``samples`` (the measurement it was chosen
        on): :func:`abrdf_jax.reconstruct` with :attr:`config` and :attr:`params` for an RBF
        model; for the bivariate one :func:`abrdf_jax.reconstruct_bivariate` of
        :class:`~abrdf_jax.Samples` (every sample at its recorded direction) or, for
        :class:`~abrdf_jax.Measurements`, the command line's map of the slices of
        :attr:`config`'s budget at :attr:`params`' α. A learned model needs its prior:
        :func:`abrdf_jax.prior.reconstruct_prior` or :func:`~abrdf_jax.prior.reconstruct_fused`.
        """
        if self.name == BIVARIATE:
            from .._bivariate import BivariateModel, reconstruct_bivariate

            if not hasattr(samples, "to_measurements") and hasattr(samples, "count"):
                apply = BivariateModel(self.config.budget).operator(self.params, samples)
                return apply(np.asarray(samples.y)[None])[0]
            return reconstruct_bivariate(samples)
        if self.name in LEARNED:
            raise InputError(
                f"Selection.reconstruct: the {self.name} model needs its prior: call "
                f"abrdf_jax.prior.reconstruct_{self.name} with it"
            )
        from .._pipeline import reconstruct

        return reconstruct(samples, self.config, self.params)

    def evidence(self) -> dict:
        """The record's ``candidates`` (each with its held-out error, rank and description) and
        ``isotropy`` (the report's dictionary): what :meth:`to_dict` holds beyond the model."""
        return {
            "candidates": [
                {
                    "name": n,
                    "held_out_log_rms": _finite(self.errors[n]),
                    "rank": self.ranks[n],
                    "description": description(n),
                }
                for n in sorted(self.errors, key=lambda n: self.ranks[n])
            ],
            "isotropy": None if self.isotropy is None else self.isotropy.to_dict(),
        }


def _finite(x):
    return float(x) if math.isfinite(x) else None


class Plan(NamedTuple):
    """A measurement's selection before the held-out errors: its candidates and the evidence."""

    meas: object  # Measurements, or the command line's numpy slices
    alpha: float
    budget: str | None
    report: IsotropyReport | None
    configs: dict
    ranks: dict
    #: ``{"iso": Config}`` in the automatic plan of an isotropic material (the test's verdict,
    #: no axial slices, or a forced ``iso102``): ``iso`` is scored where there is a comparison
    #: (an RBF has held-out errors; beside a prior's models) but stands for the isotropic
    #: models, and chosen it gives the bivariate model, on the slices of the configuration's
    #: budget (:func:`finish`). Not in an anisotropic plan: there ``iso`` is the RBF's
    #: diagonal-only model, which keeps some of the φ dependence that the bivariate model drops.
    stand_in: dict = {}


def check_budget(budget) -> None:
    if budget not in (None, "iso102", "aniso204"):
        raise InputError(f"budget must be 'iso102', 'aniso204' or None, got {budget!r}")


def plan(meas, alpha: float, candidates, budget, noise, level, min_effect, report=None) -> Plan:
    """Test isotropy and list the candidates left for a grouped measurement (everything before
    the folds; numpy: the isotropy test and its χ² tail need no JAX). ``report``: its isotropy
    test with these ``noise``, ``level`` and ``min_effect``, if made
    already (:func:`~abrdf_jax.select._isotropy.isotropy_tests`: a folder's at once)."""
    check_budget(budget)
    if budget == "aniso204" and not meas.has_axial:
        raise InputError("budget 'aniso204' needs axial slices, but the measurement has none")
    if budget is not None:
        report, aniso_ok = None, budget == "aniso204"
    else:
        if report is None:
            report = isotropy_test(meas, noise=noise, level=level, min_effect=min_effect)
        aniso_ok = not report.isotropic
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
    configs = {n: _candidate_config(n, meas.pairs) for n in names}
    ranks = {n: CANDIDATES[n].rank for n in names}
    stand_in = {}
    if candidates == "auto" and not aniso_ok:  # isotropic: the bivariate model, every slice read
        b = "aniso204" if budget != "iso102" and meas.has_axial else "iso102"
        key = (BIVARIATE, b, repr(meas.pairs))  # made once per budget and pairs, as below
        stand_in = {"iso": _CONFIGS.get(key, lambda: Config(budget=b, pairs=meas.pairs))}
    return Plan(meas, alpha, budget, report, configs, ranks, stand_in)


def _candidate_config(name: str, pairs) -> Config:
    """``CANDIDATES[name].config(pairs=pairs)``, made once per name and pairs (a folder's files
    share them; a :class:`Config` is frozen). Keyed by the pairs' ``repr``: pairs that print
    alike are the same values of the same types."""
    return _CONFIGS.get((name, repr(pairs)), lambda: CANDIDATES[name].config(pairs=pairs))


_CONFIGS = BoundedMemo(256)


def with_prior(p: Plan, fused: bool = False) -> Plan:
    """The plan with the prior-only model (and with ``fused`` the fused model) among its
    candidates (ranks in :data:`LEARNED`), on the slices of the plan's budget: all of them when
    an anisotropic candidate is left, else the diagonal ones (``iso102``). Their configuration
    only says that budget."""
    budget = "aniso204" if any(c.budget == "aniso204" for c in p.configs.values()) else "iso102"
    names = [n for n in LEARNED if fused or n == PRIOR]
    configs = {**p.configs, **{n: Config(budget=budget, pairs=p.meas.pairs) for n in names}}
    return p._replace(configs=configs, ranks={**p.ranks, **{n: LEARNED[n][0] for n in names}})


def rbf_configs(configs: dict) -> dict:
    """The RBF candidates of a plan's configurations (all but the learned models)."""
    return {n: c for n, c in configs.items() if n not in LEARNED}


def fused_gate(errors: dict[str, float]) -> tuple[dict[str, float], str]:
    """The errors the tolerance rule compares, and a note for the reason: the fused model only
    where the prior alone is held out at least as well as the best RBF model.

    Why: the fused model's held-out samples lie on the measured slices, where its kernel on the
    residual catches what the prior misses; away from the slices its mean reverts to the prior.
    A material that the database explains worse than the kernel does (the prior alone worse held
    out) falls back to the RBF models (issue 14: not pulled towards the database). On the
    built-in analytic materials this keeps the RBF on ggx-aniso-metal and rough-grooves, where
    the fused model's table is worse (``python -m benchmarks.fused_operator``; the rule was
    written after that table, so the table does not test it independently).
    """
    rbf = {n: e for n, e in errors.items() if n not in LEARNED and math.isfinite(e)}
    if FUSED not in errors or PRIOR not in errors or not rbf:
        return errors, ""
    best = min(rbf, key=rbf.get)
    if not errors[PRIOR] > rbf[best]:
        return errors, ""
    kept = {n: e for n, e in errors.items() if n != FUSED}
    note = (
        f" (fused left out: the prior alone is held out worse than {best}, "
        f"{errors[PRIOR]:.4g} > {rbf[best]:.4g}: a material unlike the prior's database)"
    )
    return kept, note


def finish(
    plan: Plan, errors: dict | None, tol: float, k: int, seconds: float, make_params=None
) -> Selection:
    """The tolerance rule on the held-out errors (``None``: a single candidate).

    ``make_params(config, alpha_deg, dtype)`` makes the chosen model's parameters: by default
    their numpy values (:func:`abrdf_jax._config.default_values`); :func:`select_model` passes
    :meth:`abrdf_jax.Params.default`."""
    names = list(plan.configs)
    if errors is None:
        errors = {names[0]: float("nan")}
        pick = names[0]
        reason = f"{pick}: the only candidate left"
    else:
        compared, note = fused_gate(errors)
        pick, reason = tolerance_choice(compared, plan.ranks, tol)
        reason += note
    if plan.report is not None:
        reason = f"{plan.report.reason}. {reason}"
    elif plan.budget is not None:
        reason = f"budget forced to {plan.budget}. {reason}"
    config, ranks = plan.configs[pick], plan.ranks
    if pick in plan.stand_in:  # an isotropic model wins: the bivariate one
        config, ranks = plan.stand_in[pick], {**ranks, BIVARIATE: BIVARIATE_RANK}
        reason += (
            f". {pick} stands for the isotropic models: {BIVARIATE}, {description(BIVARIATE)} "
            f"({config.budget})"
        )
        pick = BIVARIATE
    params = (make_params or default_values)(config, plan.alpha, plan.meas.y.dtype)
    return Selection(pick, config, params, errors, ranks, plan.report, reason, tol, k, seconds)


def quick_selection(
    meas,
    alpha_deg: float,
    *,
    budget: str | None = None,
    tol: float = TOL,
    k: int = 4,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
) -> Selection | None:
    """:func:`select_model` (``candidates="auto"``) of a grouped measurement when the choice needs
    no held-out errors (one candidate left: no axial slices, an isotropic material or a forced
    budget with one model), without JAX (its ``params`` are numpy values,
    :class:`abrdf_jax._config.ParamValues`); ``None`` when the candidates must be compared."""
    t0 = time.perf_counter()
    p = plan(meas, alpha_deg, "auto", budget, noise, level, min_effect)
    if len(p.configs) > 1:
        return None
    return finish(p, None, tol, k, time.perf_counter() - t0)


def _group_key(config: Config):
    """Configurations with equal keys share the RBF system (and the default parameters) and
    the samples it is fitted from (spike cap, slice smoothing)."""
    fields = (
        "kernel",
        "degree",
        "value_space",
        "parameterization",
        "log_eps",
        "spike_cap",
        "slice_smoothing",
    )
    return tuple(getattr(config, f) for f in fields)


def group_configs(configs: dict[str, Config]) -> list[tuple[tuple[str, ...], tuple[Config, ...]]]:
    """Split named configurations into groups that share one RBF system."""
    groups: dict = {}
    for name, cfg in configs.items():
        groups.setdefault(_group_key(cfg), []).append((name, cfg))
    return [(tuple(n for n, _ in g), tuple(c for _, c in g)) for g in groups.values()]


def entry_groups(configs: dict) -> list[tuple[tuple[str, ...], tuple[Config, ...]]]:
    """The named configurations in groups whose held-out fits are computed together in numpy
    (a held-out entry of :mod:`abrdf_jax.select._held_out_entry`, or a dense capture's
    :func:`abrdf_jax.select._dense_held_out.dense_errors` call): one RBF system
    (:func:`~abrdf_jax.select.group_configs`) and one slice interpolation."""
    out = []
    for names, cfgs in group_configs(configs):
        by_interp: dict = {}
        for n, c in zip(names, cfgs):
            by_interp.setdefault(c.interp, []).append((n, c))
        out += [(tuple(n for n, _ in g), tuple(c for _, c in g)) for g in by_interp.values()]
    return out
