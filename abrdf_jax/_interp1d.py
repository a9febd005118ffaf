"""Periodic 1D interpolation of a slice: samples at sorted angles in ``[0, 2π)``, padded.

A slice is stored as ``t`` (``(nmax,)``, radians, sorted ascending, the first ``n`` valid) and
values ``y`` (``(nmax, C)``). Padding lets slices of different lengths share one array so that a
whole measurement is one pytree of fixed shape (one compilation for any sample count up to
``nmax``). The count ``n`` may be traced.

Methods:
- ``"linear"``: periodic piecewise linear (the paper's choice is not stated; this is the
  simplest and it never overshoots, so min/max of the interpolant equal those of the samples).
- ``"cubic"``: periodic Catmull–Rom (cubic Hermite, tangents by non-uniform central
  differences): C¹, exact for linear data, may overshoot near sharp peaks.
"""

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._names import INTERP_METHODS

TWO_PI = 2.0 * jnp.pi
METHODS = INTERP_METHODS


def _neighbours(t, n, tq):
    """Indices of the knots left/right of each query and their unwrapped angles."""
    nmax = t.shape[0]
    valid = jnp.arange(nmax, dtype=jnp.asarray(n).dtype) < n
    tk = jnp.where(valid, t, jnp.inf)
    j = jnp.searchsorted(tk, tq, side="right")  # knots <= tq, in [0, n]
    jl = jnp.where(j == 0, n - 1, j - 1)
    jr = jnp.where(j >= n, 0, j)
    tl = t[jl] - jnp.where(j == 0, TWO_PI, 0.0)
    tr = t[jr] + jnp.where(j >= n, TWO_PI, 0.0)
    return jl, jr, tl, tr


def periodic_interp(
    t: Float[Array, " nmax"],
    y: Float[Array, "nmax C"],
    n: Int[Array, ""] | int,
    tq: Float[Array, " Q"],
    method: str = "linear",
) -> Float[Array, "Q C"]:
    """Interpolate a periodic slice at query angles.

    Args:
        t: knot angles (radians) sorted ascending in ``[0, 2π)``; entries past ``n`` are padding.
        y: knot values.
        n: number of valid knots (>= 1).
        tq: query angles (radians, any range; wrapped modulo 2π).
        method: ``"linear"`` or ``"cubic"``.

    Returns:
        Interpolated values, shape ``(Q, C)``.
    """
    if method not in METHODS:
        raise ValueError(f"interpolation method must be one of {METHODS}, got {method!r}")
    tq = jnp.mod(tq, TWO_PI)
    jl, jr, tl, tr = _neighbours(t, n, tq)
    h = tr - tl
    # Coincident knots (duplicated angles) give h == 0: take the left value (double where so
    # that the gradient stays finite).
    ok = h > 0
    hs = jnp.where(ok, h, 1.0)
    u = jnp.where(ok, (tq - tl) / hs, 0.0)[:, None]
    yl, yr = y[jl], y[jr]
    if method == "linear":
        return (1.0 - u) * yl + u * yr
    # Catmull-Rom with non-uniform central differences (periodic neighbours).
    jll = jnp.mod(jl - 1, n)
    jrr = jnp.mod(jr + 1, n)
    tll = tl - _gap_left(t, n, jl)
    trr = tr + _gap_right(t, n, jr)
    yll, yrr = y[jll], y[jrr]
    ml = _slope(yll, yr, tr - tll)
    mr = _slope(yl, yrr, trr - tl)
    u2, u3 = u * u, u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    hh = h[:, None]
    return h00 * yl + h10 * hh * ml + h01 * yr + h11 * hh * mr


def _slope(a, b, dt):
    ok = dt > 0
    return jnp.where(ok[:, None], (b - a) / jnp.where(ok, dt, 1.0)[:, None], 0.0)


def _gap_left(t, n, j):
    """Angular gap from knot ``j`` back to its periodic predecessor."""
    jp = jnp.mod(j - 1, n)
    return jnp.where(j == 0, t[j] + TWO_PI - t[jp], t[j] - t[jp])


def _gap_right(t, n, j):
    """Angular gap from knot ``j`` forward to its periodic successor."""
    jn = jnp.mod(j + 1, n)
    return jnp.where(j == n - 1, t[jn] + TWO_PI - t[j], t[jn] - t[j])
