"""Radial-basis-function interpolation: fit once, evaluate many times.

``y(x) = Σ_j c_j φ(r²(x, x_j)) + Σ_k p_k P_k(x)`` with ``r²`` scaled by per-dimension widths and an
optional polynomial tail ``P`` (monomials up to ``degree`` of the *shifted and scaled* coordinates,
as scipy does, which keeps the system well scaled). The coefficients solve

``[[K + λI, P], [Pᵀ, 0]] [c; p] = [y; 0]``

with ``λ`` the regularisation (scipy's ``smoothing``). Positive-definite kernels without a tail
are solved by Cholesky (with the nugget ``λ``); otherwise the system is indefinite and solved by LU,
with the polynomial block scaled to the kernel block's magnitude (an exact change of variables that
keeps the scale of a wide-range kernel such as the thin-plate spline out of the condition number).
The Gram matrix depends only on the centres and widths, never on the values: one factorisation
serves every channel and every material (vmap over values reuses it).

**Guard** (``guard=True``, the default). After factorising, the 1-norm condition number ``κ`` of
the system is estimated from the factor (Hager 1984 / Higham 1988, the estimator behind LAPACK's
``xGECON``: a few solves with the factor, ``O(n²)`` each). The system counts as *singular to
working precision* when ``κ ≥ 1/ε`` (``ε`` the machine epsilon of the dtype; LAPACK's ``xGESVX``
uses the same test) or when the factor is not finite (a Cholesky of a matrix that is not positive
definite in floating point). Then the system is factorised once more, with the regularisation
raised to

``λ₁ = max(10 λ, GUARD_FACTOR · ε · ‖K‖₁)``  (``GUARD_FACTOR = 100``),

and that solution is used. For a positive-definite kernel ``κ₂(K + λ₁I) ≤ 1 + ‖K‖₂/λ₁ ≤
1 + 1/(100 ε)``, a hundredth of the threshold (the 1-norm condition exceeds it by at most a
factor ``n``, in practice by a small one), so one retry nearly always suffices; for the
conditionally positive-definite kernels with a polynomial tail ``benchmarks/stability.py``
measures it. If the raised
system is still singular to working precision, :class:`SolveInfo` says ``ok = False``. On a
well-conditioned system nothing changes: the requested ``λ`` is used and the result is the plain
solve's bit for bit. The choice of ``λ`` is made on a stopped-gradient copy of the matrix (a
``lax.while_loop`` of at most two attempts: the second factorisation runs only when needed, and
outside ``vmap`` over values, which never changes the matrix); the
coefficients are then obtained by ``lax.custom_linear_solve`` with the chosen factor, which
differentiates implicitly (``dc = -A⁻¹ dA c``), so a failed attempt never leaks NaN into gradients.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Bool, Float, Int

from ._config import resolve_degree as resolve_degree
from ._kernels import is_positive_definite
from ._rbf_system import GUARD_FACTOR as GUARD_FACTOR, evaluate, gram as gram, prepared
from ._rbf_system import hager_start, norm1 as _norm1, raised_reg
from ._rbf_system import system as _system


class RBFInterpolant(eqx.Module):
    """A fitted RBF interpolant (centres, widths and coefficients); call it to evaluate."""

    centres: Float[Array, "n d"]
    widths: Float[Array, " d"]
    coeffs: Float[Array, "n C"]
    poly_coeffs: Float[Array, "m C"]
    shift: Float[Array, " d"]
    scale: Float[Array, " d"]
    kernel: str = eqx.field(static=True)
    degree: int = eqx.field(static=True)

    def __call__(self, x: Float[Array, "q d"]) -> Float[Array, "q C"]:
        return evaluate(
            x, self.centres, self.widths, self.coeffs, self.poly_coeffs, self.shift, self.scale,
            self.kernel, self.degree, jnp,
        )  # fmt: skip


class SolveInfo(eqx.Module):
    """How an RBF system was solved (see the module docstring, "Guard").

    Attributes:
        reg: the regularisation ``λ`` actually used.
        cond: the estimated 1-norm condition number of the solved system at that ``λ``
            (``inf`` when the factorisation failed).
        ok: the system was finite and not singular to working precision (``cond < 1/ε``).
        retries: how many times ``λ`` was raised (0: the requested ``λ`` was used).
    """

    reg: Float[Array, ""]
    cond: Float[Array, ""]
    ok: Bool[Array, ""]
    retries: Int[Array, ""]


def inverse_norm1_estimate(solve, n: int, dtype, steps: int = 3):
    """Lower estimate of ``‖A⁻¹‖₁`` for a symmetric ``A`` from a solver ``b ↦ A⁻¹ b``.

    Hager's ascent (W. W. Hager, "Condition estimates", SIAM J. Sci. Stat. Comput. 5, 1984; the
    method behind LAPACK's ``xGECON``) run from four starting vectors at once: the constant
    vector, Higham's alternating ramp (ACM TOMS 14(4), 1988) and two fixed random sign vectors.
    Each of the ``steps`` iterations is one solve with an ``(n, 4)`` right-hand side: ``y = A⁻¹x``
    (the estimate is the largest ``‖y‖₁/‖x‖₁`` seen), then ``z = A⁻ᵀ sign(y)`` (``A`` symmetric:
    the same solver) and the next ``x = e_j`` at ``j = argmax |z|``. The loop keeps a single solve
    in the compiled program (XLA expands every triangular solve call site separately, which is
    what compile time is spent on). ``benchmarks/stability.py`` compares it with the exact
    condition number in float64.
    """
    x0 = jnp.asarray(hager_start(n), dtype)

    def step(k, carry):
        x, est = carry
        w = solve(x)
        est = jnp.where(
            k % 2 == 0,
            jnp.maximum(est, jnp.max(jnp.sum(jnp.abs(w), 0) / jnp.sum(jnp.abs(x), 0))),
            est,
        )
        sign = jnp.where(w >= 0, 1.0, -1.0).astype(dtype)
        unit = jax.nn.one_hot(jnp.argmax(jnp.abs(w), axis=0), n, dtype=dtype).T
        return jnp.where(k % 2 == 0, sign, unit), est

    return jax.lax.fori_loop(0, steps, step, (x0, jnp.zeros((), dtype)))[1]


def _factorize(a, chol: bool):
    """Factor of ``a`` (Cholesky or LU with pivots) and its solver."""
    if chol:
        c, _ = jsl.cho_factor(a, lower=True)
        return (c, jnp.zeros((0,), jnp.int32))
    lu, piv = jsl.lu_factor(a)
    return (lu, piv)


def _factor_solve(factor, b, chol: bool):
    if chol:
        return jsl.cho_solve((factor[0], True), b)
    return jsl.lu_solve(factor, b)


def _guarded_factor(k, p, lam, chol: bool, guard: bool):
    """Factorise the system; refactorise at a larger ``λ`` if it is singular to working precision.

    Runs on stopped-gradient inputs: returns the factor and the diagnostics (with ``λ`` used).
    """
    k, p, lam = jax.lax.stop_gradient((k, p, lam))
    dtype = k.dtype
    eps = jnp.finfo(dtype).eps

    def attempt(lam_j):
        a = _system(k, p, lam_j)
        fac = _factorize(a, chol)
        inv = inverse_norm1_estimate(lambda b: _factor_solve(fac, b, chol), a.shape[0], dtype)
        cond = _norm1(a) * inv
        finite = jnp.isfinite(cond) & jnp.all(jnp.isfinite(fac[0]))
        cond = jnp.where(finite, cond, jnp.inf)
        return fac, cond, finite & (cond * eps < 1.0)

    if not guard:
        fac, cond, ok = attempt(lam)
        return fac, SolveInfo(lam, cond, ok, jnp.asarray(0, jnp.int32))
    # For a positive-definite K, κ₂(K + λ₁I) ≤ 1 + ‖K‖₂/λ₁ ≤ 1 + ‖K‖₁/λ₁ ≤ 1 + 1/(GUARD_FACTOR ε):
    # well inside the test above. (With a polynomial tail the saddle-point system has no such
    # bound; benchmarks/stability.py measures it.)
    lam1 = raised_reg(lam, k, jnp)

    # One loop body (factorise + estimate) run once, or twice when the first attempt fails: a
    # while_loop compiles the factorisation once, where lax.cond would compile it twice.
    def body(state):
        j = state[3]
        fac, cond, ok = attempt(jnp.where(j == 0, lam, lam1))
        return fac, cond, ok, j + 1

    shapes = jax.eval_shape(lambda: _factorize(_system(k, p, lam), chol))
    init = (
        jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), shapes),
        jnp.asarray(jnp.inf, dtype),
        jnp.asarray(False),
        jnp.asarray(0, jnp.int32),
    )
    fac, cond, ok, j = jax.lax.while_loop(lambda st: ~st[2] & (st[3] < 2), body, init)
    retries = j - 1
    return fac, SolveInfo(jnp.where(retries > 0, lam1, lam), cond, ok, retries)


@functools.partial(jax.jit, static_argnames=("chol", "guard"))
def _solve(k, p, s, reg, y, chol: bool, guard: bool):
    """Solve the (guarded) system for the kernel and polynomial coefficients."""
    n, m = k.shape[0], p.shape[1]
    fac, info = _guarded_factor(k, p, reg, chol, guard)
    # λ's gradient path: the requested λ when it was kept, else the raised λ₁ = max(10 λ, const),
    # which still depends on λ in its first branch (so a tuner can move λ out of the guarded range).
    floor = jax.lax.stop_gradient(GUARD_FACTOR * jnp.finfo(k.dtype).eps * _norm1(k))
    lam = jnp.where(info.retries == 0, reg, jnp.maximum(10.0 * reg, floor))
    a = _system(k, p, lam)
    rhs = jnp.concatenate([y, jnp.zeros((m, y.shape[1]), y.dtype)]) if m else y
    fac = jax.lax.stop_gradient(fac)
    sol = jax.lax.custom_linear_solve(
        lambda v: jnp.matmul(a, v, precision=jax.lax.Precision.HIGHEST),
        rhs,
        lambda _, b: _factor_solve(fac, b, chol),
        symmetric=True,
    )
    return sol[:n], sol[n:] * s, info


def fit_rbf_info(
    x: Float[Array, "n d"],
    y: Float[Array, "n C"],
    widths: Float[Array, " d"],
    kernel: str = "gaussian",
    reg: Float[Array, ""] | float = 0.0,
    degree: int | None = None,
    *,
    guard: bool = True,
) -> tuple[RBFInterpolant, SolveInfo]:
    """Fit an RBF interpolant and report how its system was solved.

    Args:
        x: centres, shape ``(n, d)``.
        y: values, shape ``(n, C)`` (all channels share one factorisation).
        widths: per-dimension widths ``ℓ`` (positive), shape ``(d,)`` or scalar.
        kernel: one of :data:`abrdf_jax._kernels.KERNELS`.
        reg: regularisation ``λ`` added to the Gram diagonal (scipy's ``smoothing``).
        degree: polynomial tail degree; ``None``: the kernel's minimum (-1 = none).
        guard: raise ``λ`` when the system is singular to working precision (module docstring);
            ``False`` solves exactly as asked (for the stability benchmark).

    Returns:
        ``(interpolant, info)``: the fitted :class:`RBFInterpolant` and a :class:`SolveInfo`.
    """
    degree, widths, shift, scale, (k, p, s) = prepared(x, widths, kernel, degree, jnp)
    reg = jnp.asarray(reg, x.dtype)
    chol = degree < 0 and is_positive_definite(kernel)
    coeffs, poly, info = _solve(k, p, s, reg, y, chol=chol, guard=guard)
    return RBFInterpolant(x, widths, coeffs, poly, shift, scale, kernel, degree), info


def fit_rbf(
    x: Float[Array, "n d"],
    y: Float[Array, "n C"],
    widths: Float[Array, " d"],
    kernel: str = "gaussian",
    reg: Float[Array, ""] | float = 0.0,
    degree: int | None = None,
    *,
    guard: bool = True,
) -> RBFInterpolant:
    """Fit an RBF interpolant to values ``y`` at centres ``x``: :func:`fit_rbf_info` without the
    diagnostics (same arguments)."""
    return fit_rbf_info(x, y, widths, kernel, reg, degree, guard=guard)[0]


def rbf_system(
    x: Float[Array, "n d"],
    widths: Float[Array, " d"],
    kernel: str = "gaussian",
    reg: Float[Array, ""] | float = 0.0,
    degree: int | None = None,
) -> Float[Array, "N N"]:
    """The matrix :func:`fit_rbf` factorises at ``λ = reg`` (for diagnostics: an exact condition number).

    ``[[K + λI, P s], [(P s)ᵀ, 0]]`` with the polynomial block scaled to the kernel block's
    magnitude (module docstring); ``N = n + m``, ``m`` the number of tail monomials.
    """
    k, p, _ = prepared(x, widths, kernel, degree, jnp)[-1]
    return _system(k, p, jnp.asarray(reg, x.dtype))


def rbf_interpolate(x, y, xq, widths, kernel="gaussian", reg=0.0, degree=None):
    """One-shot convenience: fit at ``x`` and evaluate at ``xq``."""
    return fit_rbf(x, y, widths, kernel, reg, degree)(xq)
