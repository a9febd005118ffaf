"""One small fitting API over optimistix and jaxopt.

``fit(problem, data, params, solver=...)`` minimises a tuning problem (:mod:`abrdf_jax.tuning._problems`)
and returns a :class:`FitResult`. Solvers:

========  ===========================================  ==================================
name      algorithm                                    library
========  ===========================================  ==================================
``lm``    Levenberg–Marquardt on the residuals          ``optimistix.LevenbergMarquardt``
``gn``    Gauss–Newton on the residuals                 ``optimistix.GaussNewton``
``bfgs``  BFGS on half the mean squared residual        ``optimistix.BFGS``
``lbfgs`` L-BFGS on the same scalar                     ``jaxopt.LBFGS``
``lbfgsb`` L-BFGS-B with box bounds on log-width/log-λ   ``jaxopt.LBFGSB``
========  ===========================================  ==================================

The whole solve is one compiled program (the solver's loop is a ``lax.while_loop``), compiled
ahead of time once per (problem, solver, step budget, data shapes): new data or starting values
never recompile, and the compile time is reported apart from the solve time. Progress comes from
a host callback in the objective (one line per evaluation batch, or a user callback).
``progress=None`` compiles the program without that callback: JAX never stores a program with a
host callback in its persistent compilation cache, so only such a fit is loaded from the cache by
the next process (``abrdf-jax fit -q``); it does not count evaluations. A fit that
produces non-finite parameters or loss ends with ``status="diverged"`` and returns the starting
parameters, never NaN. A fit that ends above its starting loss keeps the starting parameters,
and that and any free parameter left at a bound of its space are listed in
``FitResult.warnings``.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._params import Params
from ._problems import AbstractProblem
from ._solvers import SOLVERS as _SOLVERS

SOLVERS = tuple(_SOLVERS)
LEAST_SQUARES = tuple(name for name, (_, ls) in _SOLVERS.items() if ls)


@dataclass
class FitResult:
    """What a fit returns.

    Attributes:
        params: the fitted :class:`Params` (the starting ones if the fit diverged).
        theta: the unconstrained coordinates of ``params``.
        status: ``"converged"``, ``"max_steps"`` (budget used up; the result is still the best
            point reached by the solver), ``"diverged"`` (non-finite loss or parameters) or
            ``"failed"`` (the solver reported another failure).
        loss_initial, loss_final: the objective (half the mean squared residual) before and after.
        steps: solver iterations; evaluations: objective evaluations seen by the progress hook
            (``None`` with ``progress=None``: no hook).
        seconds: wall time of the solve; compile_seconds: of its compilation.
        history: the objective at every evaluation, in order.
        solver: the solver's name; message: the solver's own result text.
        warnings: what makes the result doubtful, one phrase each: parameters at a bound of
            the parameter space, or a loss that rose (then the starting parameters are kept).
    """

    params: Params
    theta: dict
    status: str
    loss_initial: float
    loss_final: float
    steps: int
    evaluations: int | None
    seconds: float
    compile_seconds: float
    solver: str
    message: str = ""
    history: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.status in ("converged", "max_steps")

    def summary(self) -> dict:
        """JSON-friendly summary (no arrays but the parameters as lists)."""
        p = self.params
        return {
            "solver": self.solver,
            "status": self.status,
            "message": self.message,
            "loss_initial": self.loss_initial,
            "loss_final": self.loss_final,
            "steps": self.steps,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "compile_seconds": self.compile_seconds,
            "alpha_deg": p.alpha_deg,
            "widths": [float(w) for w in np.asarray(p.widths)],
            "reg": float(p.reg),
            "warnings": list(self.warnings),
        }


# The progress hook: a module-level sink so that the compiled program never depends on it.
_SINK: list[Callable[[float], None]] = []


def _report(value):
    v = float(np.asarray(value))
    for f in _SINK:
        f(v)


def _objective(problem: AbstractProblem, hook: bool, theta, data, least_squares: bool):
    r = problem.residuals(theta, data)
    loss = 0.5 * jnp.mean(r * r)
    if hook:  # static: without it the program has no host callback and can be cached
        jax.debug.callback(_report, loss)
    return r if least_squares else loss


def _solve(problem, solver_name, max_steps, rtol, atol, hook, theta0, data, lo, hi):
    """The whole solve; returns (theta, steps, status code, loss at theta0, loss at theta)."""
    initial = problem.loss(theta0, data)
    run, _ = _SOLVERS[solver_name]
    objective = functools.partial(_objective, problem, hook)  # (theta, data, least_squares)
    theta, steps, code = run(objective, theta0, data, max_steps, rtol, atol, lo, hi)
    final = problem.loss(theta, data)
    return theta, steps, code, initial, final


_solve_jit = jax.jit(_solve, static_argnums=(0, 1, 2, 3, 4, 5))


def fit(
    problem: AbstractProblem,
    data,
    params: Params,
    *,
    solver: str = "lm",
    max_steps: int = 50,
    rtol: float = 1e-4,
    atol: float = 1e-6,
    progress: bool | Callable[[float], None] = False,
) -> FitResult:
    """Fit the free parameters of ``problem`` on ``data`` starting from ``params``.

    Args:
        problem: a :class:`~abrdf_jax.tuning.SelfCalibration` or
            :class:`~abrdf_jax.tuning.Population` problem (static choices).
        data: its data pytree (``problem.make_data(...)``); arrays only.
        params: starting (and fixed, for the parameters that are not free) :class:`Params`.
        solver: one of :data:`SOLVERS`.
        max_steps: iteration budget of the solver.
        rtol, atol: the solver's tolerances (jaxopt uses ``atol`` on the gradient norm).
        progress: ``True`` prints the objective at each evaluation batch to stderr; a callable
            receives every objective value instead; ``False`` counts the evaluations only;
            ``None``: no host callback in the compiled program (so JAX's persistent
            compilation cache, when on, stores it and the next process loads it), no
            ``history`` and ``evaluations=None``.

    Returns:
        A :class:`FitResult`.
    """
    if solver not in SOLVERS:
        raise InputError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise InputError(f"max_steps must be a positive int, got {max_steps!r}")
    theta0 = problem.space.init(params)
    lo, hi = problem.space.bounds(theta0)
    data = dict(data, base=params)
    history: list[float] = []

    def sink(v):
        history.append(v)
        if callable(progress):
            progress(v)
        elif progress:
            import sys

            print(
                f"  fit[{solver}] eval {len(history):4d}  loss {v:.6g}", file=sys.stderr, flush=True
            )

    static = (problem, solver, max_steps, float(rtol), float(atol), progress is not None)
    t0 = time.perf_counter()
    compiled = _solve_jit.lower(*static, theta0, data, lo, hi).compile()
    t_compile = time.perf_counter() - t0
    _SINK.append(sink)
    try:
        t0 = time.perf_counter()
        theta, steps, code, loss0, final = compiled(theta0, data, lo, hi)
        final = float(jax.block_until_ready(final))
        seconds = time.perf_counter() - t0
    finally:
        _SINK.remove(sink)
    loss0 = float(loss0)
    finite = math.isfinite(final) and all(
        bool(jnp.all(jnp.isfinite(v))) for v in jax.tree_util.tree_leaves(theta)
    )
    code = int(code)
    if not finite:
        status, theta, final = "diverged", theta0, loss0
    else:
        status = ("converged", "max_steps", "failed")[code]
    fitted = problem.space.to_params(theta, params)
    message = {
        0: "tolerance reached",
        1: f"stopped after max_steps={max_steps}",
        2: "the solver reported a failure",
    }[code]
    warnings = []
    if status == "diverged":
        message = "non-finite loss or parameters; returned the starting parameters"
    elif final > loss0:  # a solver may end above its start (a failed line search, a bound)
        warnings.append(
            f"the loss rose from {loss0:.5g} to {final:.5g}; kept the starting parameters"
        )
        theta, final = theta0, loss0
        fitted = problem.space.to_params(theta, params)
    warnings += problem.space.at_bounds(fitted)
    return FitResult(
        params=fitted,
        theta=theta,
        status=status,
        loss_initial=loss0,
        loss_final=final,
        steps=int(steps),
        evaluations=None if progress is None else len(history),
        seconds=seconds,
        compile_seconds=t_compile,
        solver=solver,
        message=message,
        history=history,
        warnings=warnings,
    )


def held_out_loss(problem: AbstractProblem, data, params: Params) -> float:
    """The objective of ``problem`` at ``params`` (jitted once per problem and data shape)."""
    theta = problem.space.init(params)
    return float(_loss_jit(problem, theta, dict(data, base=params)))


@eqx.filter_jit
def _loss_jit(problem, theta, data):
    return problem.loss(theta, data)
