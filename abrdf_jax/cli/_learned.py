"""The learned models of ``abrdf-jax reconstruct``: the prior-only model (``--model prior``) and
the fused model (``--model fused``: the prior plus a stationary kernel on the residual), with
``--prior FILE|default``: which prior a run uses, and its model record. Used through
:mod:`abrdf_jax.cli._common`; no JAX on import (a stored entry is applied in numpy:
``abrdf_jax._prior_operator``, ``abrdf_jax._fused_operator``)."""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError
from .._names import LEARNED_MODELS

PRIOR_MODEL, FUSED_MODEL = LEARNED_MODELS


def wants_prior(args) -> bool:
    """Whether the run uses a prior: ``--model prior|fused``, or ``--prior`` with the automatic
    choice."""
    return args.model in LEARNED_MODELS or getattr(args, "prior", None) is not None


def check_prior_arguments(args) -> None:
    """``--prior`` belongs to ``--model prior|fused`` or the automatic choice."""
    if getattr(args, "prior", None) is None:
        return
    fixing = args.params is not None or args.preset is not None
    if fixing or args.model not in (None, "auto", *LEARNED_MODELS):
        flag = f"--model {args.model}" if args.model else "--preset/--params"
        raise InputError(
            f"--prior {args.prior} is used by --model prior, fused or auto, not with {flag}"
        )


def prior_source(args):
    """The run's :class:`abrdf_jax._prior_operator.PriorSource` (``None``: no prior wanted).

    Raises:
        InputError: a prior file that is missing, corrupt or of another version, naming it.
    """
    if not wants_prior(args):
        return None
    from .._prior_operator import resolve_prior

    return resolve_prior(args.prior, args.cache_dir)


def prior_choice(
    where: Path,
    source,
    budget: str,
    alpha: float,
    how: str,
    reason: str | None,
    extra=None,
    name: str = PRIOR_MODEL,
):
    """One input's learned model ``name`` (prior-only or fused): ``{"name", "config", "params",
    "record"}`` (as :func:`abrdf_jax.cli._record.model_choice`; ``config`` is the
    :class:`~abrdf_jax._prior_operator.PriorModel` or
    :class:`~abrdf_jax._fused_operator.FusedModel`)."""
    from .._config import Config, default_values

    if name not in LEARNED_MODELS:
        raise InputError(f"unknown learned model {name!r}; choose one of {LEARNED_MODELS}")
    if reason is None:  # a fixed model
        what = "the prior alone" if name == PRIOR_MODEL else "the prior + a kernel on its residual"
        reason = f"--model {name}: {what}, on the {budget} slices"
    rec = {"input": str(where), "model": name, "how": how}
    rec["config"] = {"budget": budget, "slices": _slices_read(budget)}
    rec["params"] = {"alpha_deg": float(alpha), "lam": source.lam}
    if name == FUSED_MODEL:
        from .._fused_operator import FusedModel as model

        rec["params"] = {"alpha_deg": float(alpha), "fused": source.fused_settings()}
    else:
        from .._prior_operator import PriorModel as model
    rec |= {"prior": source.record(), "reason": reason, **(extra or {})}
    params = default_values(Config(budget=budget), alpha)  # α for the operator's layout
    return {"name": name, "config": model(source, budget), "params": params, "record": rec}


def _slices_read(budget: str) -> str:
    """What a model record says of the slices read (iso102: the diagonal ones only)."""
    return "diagonal slices (iso102)" if budget == "iso102" else "all slices (aniso204)"


def learned_choice(item, source, name: str, budget: str, how: str, reason=None, extra=None):
    """:func:`prior_choice` of one measured input (``reason`` ``None``: a fixed model's, said
    here)."""
    return prior_choice(item.path, source, budget, item.alpha, how, reason, extra, name)


def bivariate_choice(item, budget: str, how: str = "fixed", reason=None, extra=None) -> dict:
    """The bivariate ``(θh, θd)`` model of an isotropic material, fixed (``--model bivariate``)
    or chosen (``how="auto"``, ``reason`` and ``extra`` from the selection)
    (:func:`abrdf_jax.reconstruct_bivariate`; ``config`` is its ``BivariateModel``)."""
    from .._bivariate import LOG_EPS, SMOOTHING, BivariateModel
    from .._config import Config, default_values

    reason = reason or (
        "--model bivariate: a thin-plate spline in (sqrt(theta_h), theta_d) of the log BRDF, "
        "assuming an isotropic material (docs/captures.md)"
    )
    rec = {"input": str(item.path), "model": "bivariate", "how": how, "reason": reason}
    rec["config"] = {"budget": budget, "slices": _slices_read(budget), "log_eps": LOG_EPS}
    rec["params"] = {"alpha_deg": float(item.alpha), "smoothing": SMOOTHING}
    rec |= extra or {}
    params = default_values(Config(budget=budget), item.alpha)  # α for the layout
    return {"name": "bivariate", "config": BivariateModel(budget), "params": params, "record": rec}
