"""Tuning the continuous parameters (kernel widths, λ, α) by gradient-based fitting.

Two problems share one fitting API::

    import abrdf_jax as aj
    from abrdf_jax import tuning

    # Self-calibration: one material, its own samples, leave-one-elevation-pair-out.
    prob, data, p0 = tuning.SelfCalibration.from_samples(samples, aj.Config.recommended())
    res = tuning.fit(prob, data, p0, solver="lm")
    table = aj.reconstruct(samples, prob.config, res.params)

    # Population: many training materials with dense references (differentiable in α).
    prob = tuning.Population(config=cfg, space=tuning.ParamSpace(alpha=True))
    res = tuning.fit(prob, tuning.Population.make_data(models, tables, p0), p0, solver="lbfgsb")
    tuning.save_params("params.json", cfg, res.params, fit=res.summary())

See :mod:`abrdf_jax.tuning._problems` (problems, parameter space) and :mod:`abrdf_jax.tuning._fitting` (solvers).
"""

from ._fitting import (
    FitResult as FitResult,
    SOLVERS as SOLVERS,
    fit as fit,
    held_out_loss as held_out_loss,
)
from ..io._paramfile import load_params as load_params, save_params as save_params
from ._problems import (
    AbstractProblem as AbstractProblem,
    FOLD_KINDS as FOLD_KINDS,
    LOSSES as LOSSES,
    ParamSpace as ParamSpace,
    Population as Population,
    SelfCalibration as SelfCalibration,
)
