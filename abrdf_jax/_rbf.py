"""Radial-basis-function interpolation: fit once, evaluate many times.

``y(x) = Σ_j c_j φ(r²(x, x_j)) + Σ_k p_k P_k(x)`` with ``r²`` scaled by per-dimension widths and an
optional polynomial tail ``P`` (monomials up to ``degree`` of the *shifted and scaled* coordinates,
as scipy does, which keeps the system well scaled). The coefficients solve

``[[K + λI, P], [Pᵀ, 0]] [c; p] = [y; 0]``

with ``λ`` the regularisation (scipy's ``smoothing``). Positive-definite kernels without a tail
are solved by Cholesky (with the nugget ``λ``); otherwise the system is indefinite and solved by LU.
The Gram matrix depends only on the centres and widths, never on the values: one factorisation
serves every channel and every material (vmap over values reuses it).
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Float

from ._kernels import is_positive_definite, kernel_fn, min_degree, scaled_sqdist

_HI = jax.lax.Precision.HIGHEST


def _exponents(dim: int, degree: int) -> list[tuple[int, ...]]:
    out = []
    for total in range(degree + 1):
        for combo in itertools.combinations_with_replacement(range(dim), total):
            e = [0] * dim
            for k in combo:
                e[k] += 1
            out.append(tuple(e))
    return out


def _poly(x, shift, scale, degree):
    if degree < 0:
        return jnp.zeros((x.shape[0], 0), x.dtype)
    z = (x - shift) / scale
    cols = [jnp.prod(z ** jnp.asarray(e, x.dtype), axis=-1) for e in _exponents(x.shape[1], degree)]
    return jnp.stack(cols, axis=-1)


def resolve_degree(kernel: str, degree: int | None) -> int:
    """The polynomial degree to use: ``None`` means the kernel's minimum."""
    lo = min_degree(kernel)
    if degree is None:
        return lo
    if degree < lo:
        raise ValueError(f"kernel {kernel!r} needs a polynomial tail of degree >= {lo}, got {degree}")
    return degree


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
        k = kernel_fn(self.kernel)(scaled_sqdist(x, self.centres, self.widths))
        out = jnp.matmul(k, self.coeffs, precision=_HI)
        if self.degree >= 0:
            out = out + jnp.matmul(_poly(x, self.shift, self.scale, self.degree), self.poly_coeffs, precision=_HI)
        return out


def _centre_stats(x):
    lo, hi = jnp.min(x, axis=0), jnp.max(x, axis=0)
    shift = (lo + hi) / 2
    scale = jnp.where(hi > lo, (hi - lo) / 2, 1.0)
    return jax.lax.stop_gradient(shift), jax.lax.stop_gradient(scale)


def gram(x, widths, kernel):
    """The kernel (Gram) matrix of the centres, shape ``(n, n)``."""
    return kernel_fn(kernel)(scaled_sqdist(x, x, widths))


def fit_rbf(
    x: Float[Array, "n d"],
    y: Float[Array, "n C"],
    widths: Float[Array, " d"],
    kernel: str = "gaussian",
    reg: Float[Array, ""] | float = 0.0,
    degree: int | None = None,
) -> RBFInterpolant:
    """Fit an RBF interpolant to values ``y`` at centres ``x``.

    Args:
        x: centres, shape ``(n, d)``.
        y: values, shape ``(n, C)`` (all channels share one factorisation).
        widths: per-dimension widths ``ℓ`` (positive), shape ``(d,)`` or scalar.
        kernel: one of :data:`abrdf_jax._kernels.KERNELS`.
        reg: regularisation ``λ`` added to the Gram diagonal (scipy's ``smoothing``).
        degree: polynomial tail degree; ``None``: the kernel's minimum (-1 = none).

    Returns:
        The fitted :class:`RBFInterpolant`.
    """
    degree = resolve_degree(kernel, degree)
    widths = jnp.broadcast_to(jnp.asarray(widths, x.dtype), (x.shape[1],))
    n = x.shape[0]
    k = gram(x, widths, kernel) + jnp.asarray(reg, x.dtype) * jnp.eye(n, dtype=x.dtype)
    shift, scale = _centre_stats(x)
    if degree < 0 and is_positive_definite(kernel):
        cf = jsl.cho_factor(k, lower=True)
        coeffs = jsl.cho_solve(cf, y)
        poly = jnp.zeros((0, y.shape[1]), x.dtype)
    else:
        p = _poly(x, shift, scale, degree)
        m = p.shape[1]
        a = jnp.block([[k, p], [p.T, jnp.zeros((m, m), x.dtype)]])
        rhs = jnp.concatenate([y, jnp.zeros((m, y.shape[1]), y.dtype)])
        sol = jnp.linalg.solve(a, rhs)
        coeffs, poly = sol[:n], sol[n:]
    return RBFInterpolant(x, widths, coeffs, poly, shift, scale, kernel, degree)


def rbf_interpolate(x, y, xq, widths, kernel="gaussian", reg=0.0, degree=None):
    """One-shot convenience: fit at ``x`` and evaluate at ``xq``."""
    return fit_rbf(x, y, widths, kernel, reg, degree)(xq)
