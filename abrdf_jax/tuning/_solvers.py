"""The solvers behind :func:`abrdf_jax.tuning.fit`: a registry name → run function.

Each run function takes ``(objective, theta0, data, max_steps, rtol, atol, lo, hi)``, where
``objective(theta, data, least_squares)`` returns the residual vector or the scalar loss, and
returns ``(theta, steps, code)`` with ``code`` 0 converged, 1 out of steps, 2 failed. optimistix
serves the least-squares solvers and BFGS; jaxopt (the design card's second optimiser library) is
imported here and nowhere else, in :func:`_jaxopt`.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._names import check_registry


def _optimistix(kind: str):
    def run(objective, theta0, data, max_steps, rtol, atol, lo, hi):
        import optimistix as optx

        tol, opts = dict(rtol=rtol, atol=atol), dict(args=data, max_steps=max_steps, throw=False)
        if kind in ("lm", "gn"):
            solver = (optx.LevenbergMarquardt if kind == "lm" else optx.GaussNewton)(**tol)
            sol = optx.least_squares(lambda th, d: objective(th, d, True), solver, theta0, **opts)
        else:
            sol = optx.minimise(
                lambda th, d: objective(th, d, False), optx.BFGS(**tol), theta0, **opts
            )
        steps = sol.stats["num_steps"]
        ok = sol.result == optx.RESULTS.successful
        code = jnp.where(ok, 0, jnp.where(steps >= max_steps, 1, 2))
        return sol.value, steps, code

    return run


def _jaxopt(kind: str):
    def run(objective, theta0, data, max_steps, rtol, atol, lo, hi):
        import jaxopt

        def fun(th, d):
            return objective(th, d, False)

        make, bounds = (jaxopt.LBFGS, ()) if kind == "lbfgs" else (jaxopt.LBFGSB, ((lo, hi),))
        theta, state = make(fun=fun, maxiter=max_steps, tol=atol, jit=True).run(
            theta0, *bounds, data
        )
        steps = state.iter_num
        return theta, steps, jnp.where(state.error <= atol, 0, jnp.where(steps >= max_steps, 1, 2))

    return run


#: name -> (run function, least squares?)
SOLVERS = {
    "lm": (_optimistix("lm"), True),
    "gn": (_optimistix("gn"), True),
    "bfgs": (_optimistix("bfgs"), False),
    "lbfgs": (_jaxopt("lbfgs"), False),
    "lbfgsb": (_jaxopt("lbfgsb"), False),
}
check_registry("SOLVERS", SOLVERS)
