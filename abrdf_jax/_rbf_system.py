"""The RBF system, for JAX or numpy (``xp``): the polynomial tail, the centring, the scaled
blocks, the saddle-point matrix and the guard's raised regularisation (the rule of
:mod:`abrdf_jax._rbf`, whose module docstring explains it), and the evaluation of a fitted
interpolant. :mod:`abrdf_jax._rbf` solves the system in JAX (a guarded factorisation with a
condition estimate, differentiable); :func:`host_solve` solves it in numpy for the operator
store's JAX-free build (:mod:`abrdf_jax._host_build`). No JAX import here."""

import itertools

import numpy as np

from ._config import resolve_degree
from ._kernels import kernel_block
from ._xp import namespace, stop_gradient

#: The guard's fallback regularisation is ``max(10 λ, GUARD_FACTOR · ε · ‖K‖₁)``.
GUARD_FACTOR = 100.0


def exponents(dim: int, degree: int) -> list[tuple[int, ...]]:
    """The monomials' exponents up to ``degree`` in ``dim`` variables (scipy's order)."""
    out = []
    for total in range(degree + 1):
        for combo in itertools.combinations_with_replacement(range(dim), total):
            e = [0] * dim
            for k in combo:
                e[k] += 1
            out.append(tuple(e))
    return out


def poly(x, shift, scale, degree, xp=None):
    """The tail's monomials of the shifted and scaled coordinates, ``(n, m)``."""
    xp = namespace(xp)
    if degree < 0:
        return xp.zeros((x.shape[0], 0), x.dtype)
    z = (x - shift[None]) / scale[None]
    cols = [
        xp.prod(z ** xp.asarray(e, x.dtype)[None], axis=-1) for e in exponents(x.shape[1], degree)
    ]
    return xp.stack(cols, axis=-1)


def matmul(a, b, xp):
    """``a @ b``; in JAX at the highest precision (no TF32 or bfloat16 passes on accelerators)."""
    if xp.__name__ == "numpy":
        return a @ b
    import jax

    return xp.matmul(a, b, precision=jax.lax.Precision.HIGHEST)


def evaluate(x, centres, widths, coeffs, poly_coeffs, shift, scale, kernel, degree, xp=None):
    """A fitted interpolant at ``x`` ``(q, d)``: ``(q, C)``."""
    xp = namespace(xp)
    k = kernel_block(x, centres, widths, kernel, xp)
    p = poly(x, shift, scale, degree, xp) if degree >= 0 else None
    return combine(k, p, coeffs, poly_coeffs, xp)


def combine(k, p, coeffs, poly_coeffs, xp=None):
    """``K c + P d``: a fitted interpolant from its kernel block ``k`` and tail block ``p``
    (``None``: no tail) at the points (:func:`evaluate`; the host build keeps the blocks)."""
    xp = namespace(xp)
    out = matmul(k, coeffs, xp)
    return out if p is None else out + matmul(p, poly_coeffs, xp)


def centre_stats(x, xp=None):
    """The tail's centring: midpoint and half range of the centres per dimension (constants)."""
    xp = namespace(xp)
    lo, hi = xp.min(x, axis=0), xp.max(x, axis=0)
    shift = (lo + hi) / 2
    scale = xp.where(hi > lo, (hi - lo) / 2, 1.0)
    return stop_gradient(shift, xp), stop_gradient(scale, xp)


def gram(x, widths, kernel, xp=None):
    """The kernel (Gram) matrix of the centres, shape ``(n, n)``."""
    xp = namespace(xp)
    return kernel_block(x, x, widths, kernel, xp)


def norm1(a, xp=None):
    """The matrix 1-norm (largest column sum of magnitudes)."""
    xp = namespace(xp)
    return xp.max(xp.sum(xp.abs(a), axis=0))


def blocks(x, widths, kernel, degree, shift, scale, xp=None):
    """Kernel block ``K`` and the polynomial block scaled to ``K``'s magnitude: ``(K, P s, s)``."""
    xp = namespace(xp)
    k = gram(x, widths, kernel, xp)
    p = poly(x, shift, scale, degree, xp)
    if p.shape[1]:
        kmax = stop_gradient(xp.max(xp.abs(k)), xp)
        pmax = stop_gradient(xp.max(xp.abs(p)), xp)
        s = xp.where((kmax > 0) & (pmax > 0), kmax / xp.where(pmax > 0, pmax, 1.0), 1.0)
    else:
        s = xp.ones((), x.dtype)
    return k, p * s, s


def system(k, p, lam, xp=None):
    """``[[K + λI, P], [Pᵀ, 0]]`` (``K + λI`` without a tail)."""
    xp = namespace(xp)
    n, m = k.shape[0], p.shape[1]
    a = k + lam * xp.eye(n, dtype=k.dtype)
    if m == 0:
        return a
    return xp.block([[a, p], [p.T, xp.zeros((m, m), k.dtype)]])


def coordinate_widths(widths, d: int, xp=None):
    """The widths of ``d`` coordinates: ``widths`` broadcast (a scalar or ``(d,)``), or, for
    ``(4,)`` widths of a parameterization with more than four coordinates (``"onion-hd"``),
    the four followed by their geometric mean for each further coordinate."""
    xp = namespace(xp)
    w = xp.asarray(widths)
    if w.ndim == 1 and w.shape[0] == 4 and d > 4:
        extra = xp.exp(xp.mean(xp.log(w))) * xp.ones((d - 4,), w.dtype)
        return xp.concatenate([w, extra])
    return xp.broadcast_to(w, (d,))


def prepared(x, widths, kernel, degree, xp=None):
    """Degree, widths ``(d,)``, centring and the scaled blocks ``(K, P, s)`` of a system."""
    xp = namespace(xp)
    degree = resolve_degree(kernel, degree)
    widths = coordinate_widths(xp.asarray(widths, x.dtype), x.shape[1], xp)
    shift, scale = centre_stats(x, xp)
    return (
        degree,
        widths,
        shift,
        scale,
        blocks(x, widths, kernel, max(degree, -1), shift, scale, xp),
    )


def raised_reg(lam, k, xp=None):
    """The guard's second regularisation ``λ₁ = max(10 λ, GUARD_FACTOR · ε · ‖K‖₁)``."""
    xp = namespace(xp)
    return xp.maximum(10.0 * lam, GUARD_FACTOR * xp.finfo(k.dtype).eps * norm1(k, xp))


def hager_start(n: int) -> np.ndarray:
    """The condition estimate's four starting vectors ``(n, 4)``: the constant vector, Higham's
    alternating ramp and two fixed random sign vectors (:func:`abrdf_jax._rbf.inverse_norm1_estimate`)."""
    i = np.arange(n)
    alt = np.where(i % 2 == 0, 1.0, -1.0) * (1 + i / max(n - 1, 1))
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=(n, 2))
    return np.column_stack([np.ones(n), alt, signs])


def host_guarded_solve(k, p, reg, rhs, guard: bool = True):
    """``(A⁻¹ rhs, λ)`` in numpy for the system :func:`system` of ``(K, P)`` at ``reg``, or at
    :func:`raised_reg` when it is singular to working precision (``κ₁ ε ≥ 1``, or a solution
    that is not finite): the guard's rule (``λ`` the one used).

    numpy gives no access to its LU factor, so the condition estimate is the first step of
    the JAX guard's (Hager's ascent from :func:`hager_start`): its four starting vectors are
    solved for in the same call as ``rhs`` (one factorisation), ``‖A⁻¹‖₁ ≥ max ‖A⁻¹x‖₁ /
    ‖x‖₁``. A lower bound, as JAX's three steps are, and at most as large as theirs.

    Raises:
        numpy.linalg.LinAlgError: still singular at the raised ``λ`` (or with ``guard=False``).
    """
    eps = np.finfo(k.dtype).eps
    x0 = hager_start(rhs.shape[0])
    for lam in (reg, raised_reg(reg, k, np)) if guard else (reg,):
        a = system(k, p, lam, np)
        try:
            sol = np.linalg.solve(a, np.concatenate([rhs, x0], axis=1))
        except np.linalg.LinAlgError:
            continue
        est = np.max(np.sum(np.abs(sol[:, -4:]), 0) / np.sum(np.abs(x0), 0))
        cond = norm1(a, np) * est
        if np.isfinite(cond) and cond * eps < 1.0 and np.all(np.isfinite(sol)):
            return sol[:, :-4], lam
    raise np.linalg.LinAlgError("the RBF system is singular to working precision")


def host_solve(k, p, s, reg, y, guard: bool = True):
    """The coefficients ``(c, p_coeffs, λ)`` of values ``y`` ``(n, C)`` in numpy
    (:func:`host_guarded_solve`; the tail's coefficients unscaled, as :func:`evaluate` reads
    them)."""
    n, m = k.shape[0], p.shape[1]
    rhs = np.concatenate([y, np.zeros((m, y.shape[1]), y.dtype)]) if m else y
    sol, lam = host_guarded_solve(k, p, reg, rhs, guard)
    return sol[:n], sol[n:] * s, lam
