"""The prior-only model of ``abrdf-jax reconstruct`` (``--model prior``, ``--prior FILE``): which
prior a run uses, and its model record. Used through :mod:`abrdf_jax.cli._common`; no JAX on
import (a stored prior entry is applied in numpy: ``abrdf_jax._prior_operator``)."""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError

PRIOR_MODEL = "prior"


def wants_prior(args) -> bool:
    """Whether the run uses a prior: ``--model prior``, or ``--prior`` with the automatic choice."""
    return args.model == PRIOR_MODEL or getattr(args, "prior", None) is not None


def check_prior_arguments(args) -> None:
    """``--prior`` belongs to ``--model prior`` or the automatic choice."""
    if getattr(args, "prior", None) is None:
        return
    fixing = args.params is not None or args.preset is not None
    if fixing or args.model not in (None, "auto", PRIOR_MODEL):
        flag = f"--model {args.model}" if args.model else "--preset/--params"
        raise InputError(
            f"--prior {args.prior} is used by --model prior or --model auto, not with {flag}"
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


def prior_choice(where: Path, source, budget: str, alpha: float, how: str, reason: str, extra=None):
    """One input's prior-only model: ``{"name", "config", "params", "record"}`` (as
    :func:`abrdf_jax.cli._record.model_choice`; ``config`` is the
    :class:`~abrdf_jax._prior_operator.PriorModel`)."""
    from .._config import Config, default_values
    from .._prior_operator import PriorModel

    slices = "diagonal slices (iso102)" if budget == "iso102" else "all slices (aniso204)"
    rec = {"input": str(where), "model": PRIOR_MODEL, "how": how}
    rec["config"] = {"budget": budget, "slices": slices}
    rec["params"] = {"alpha_deg": float(alpha), "lam": source.lam}
    rec |= {"prior": source.record(), "reason": reason, **(extra or {})}
    params = default_values(Config(budget=budget), alpha)  # α for the operator's layout
    return {
        "name": PRIOR_MODEL,
        "config": PriorModel(source, budget),
        "params": params,
        "record": rec,
    }
