"""Periodic 1D interpolation of a slice: samples at sorted angles in ``[0, 2π)``, padded.

A slice is stored as ``t`` (``(nmax,)``, radians, sorted ascending, the first ``n`` valid) and
values ``y`` (``(nmax, C)``). Padding lets slices of different lengths share one array so that a
whole measurement is one pytree of fixed shape (one compilation for any sample count up to
``nmax``). The count ``n`` may be traced. With ``xp=numpy`` the same code runs on the host
(the JAX-free operator build, :mod:`abrdf_jax._host_build`).

Methods:
- ``"linear"``: periodic piecewise linear (the paper's choice is not stated; this is the
  simplest and it never overshoots, so min/max of the interpolant equal those of the samples).
- ``"cubic"``: periodic Catmull–Rom (cubic Hermite, tangents by non-uniform central
  differences): C¹, exact for linear data, may overshoot near sharp peaks.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ._names import INTERP_METHODS

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float, Int

TWO_PI = 2.0 * np.pi
METHODS = INTERP_METHODS


def _neighbours(t, n, tq, xp):
    """Indices of the knots left/right of each query and their unwrapped angles."""
    nmax = t.shape[0]
    valid = xp.arange(nmax, dtype=xp.asarray(n).dtype) < n
    tk = xp.where(valid, t, np.inf)
    j = xp.searchsorted(tk, tq, side="right")  # knots <= tq, in [0, n]
    jl = xp.where(j == 0, n - 1, j - 1)
    jr = xp.where(j >= n, 0, j)
    tl = t[jl] - xp.where(j == 0, TWO_PI, 0.0)
    tr = t[jr] + xp.where(j >= n, TWO_PI, 0.0)
    return jl, jr, tl, tr


def periodic_interp(
    t: Float[Array, " nmax"],
    y: Float[Array, "nmax C"],
    n: Int[Array, ""] | int,
    tq: Float[Array, " Q"],
    method: str = "linear",
    xp=None,
) -> Float[Array, "Q C"]:
    """Interpolate a periodic slice at query angles.

    Args:
        t: knot angles (radians) sorted ascending in ``[0, 2π)``; entries past ``n`` are padding.
        y: knot values.
        n: number of valid knots (>= 1).
        tq: query angles (radians, any range; wrapped modulo 2π).
        method: ``"linear"`` or ``"cubic"``.
        xp: ``jax.numpy`` (default) or ``numpy``.

    Returns:
        Interpolated values, shape ``(Q, C)``.
    """
    if method not in METHODS:
        raise ValueError(f"interpolation method must be one of {METHODS}, got {method!r}")
    if xp is None:
        import jax.numpy as xp
    tq = xp.mod(tq, TWO_PI)
    jl, jr, tl, tr = _neighbours(t, n, tq, xp)
    h = tr - tl
    # Coincident knots (duplicated angles) give h == 0: take the left value (double where so
    # that the gradient stays finite).
    ok = h > 0
    hs = xp.where(ok, h, 1.0)
    u = xp.where(ok, (tq - tl) / hs, 0.0)[:, None]
    yl, yr = y[jl], y[jr]
    if method == "linear":
        return (1.0 - u) * yl + u * yr
    # Catmull-Rom with non-uniform central differences (periodic neighbours).
    jll = xp.mod(jl - 1, n)
    jrr = xp.mod(jr + 1, n)
    tll = tl - _gap_left(t, n, jl, xp)
    trr = tr + _gap_right(t, n, jr, xp)
    yll, yrr = y[jll], y[jrr]
    ml = _slope(yll, yr, tr - tll, xp)
    mr = _slope(yl, yrr, trr - tl, xp)
    u2, u3 = u * u, u * u * u
    h00 = 2 * u3 - 3 * u2 + 1
    h10 = u3 - 2 * u2 + u
    h01 = -2 * u3 + 3 * u2
    h11 = u3 - u2
    hh = h[:, None]
    return h00 * yl + h10 * hh * ml + h01 * yr + h11 * hh * mr


def _slope(a, b, dt, xp):
    ok = dt > 0
    return xp.where(ok[:, None], (b - a) / xp.where(ok, dt, 1.0)[:, None], 0.0)


def _gap_left(t, n, j, xp):
    """Angular gap from knot ``j`` back to its periodic predecessor."""
    jp = xp.mod(j - 1, n)
    return xp.where(j == 0, t[j] + TWO_PI - t[jp], t[j] - t[jp])


def _gap_right(t, n, j, xp):
    """Angular gap from knot ``j`` forward to its periodic successor."""
    jn = xp.mod(j + 1, n)
    return xp.where(j == n - 1, t[jn] + TWO_PI - t[j], t[jn] - t[j])
