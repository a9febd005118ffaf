"""The χ² tail of the isotropy test in numpy (no JAX, no scipy: the command line's warm path).

``P(χ²_ν ≥ q) = Q(ν/2, q/2)``, the regularised upper incomplete gamma function, by the series of
the lower function for ``x < a + 1`` and by the continued fraction of the upper one (modified
Lentz) otherwise: the classic scheme of Press et al., *Numerical Recipes* (3rd ed., §6.2). Both
converge to float64 rounding in at most a few hundred terms for the degrees of freedom of a
measurement (``ν`` up to a few thousand). The batch test of many materials with one layout
(every texel of a BTF) compares its statistics with the critical value :func:`chi2_critical`
instead, one root per layout.
"""

from __future__ import annotations

import math

import numpy as np

_TINY = 1e-300
_EPS = 1e-16
_MAX_TERMS = 100_000


def _upper_gamma(a: float, x: float) -> float:
    """``Q(a, x)`` for ``a > 0``, ``x ≥ 0``."""
    if x <= 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:  # series of P(a, x) = 1 - Q
        term = total = 1.0 / a
        n = a
        for _ in range(_MAX_TERMS):
            n += 1.0
            term *= x / n
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return max(1.0 - total * math.exp(log_front), 0.0)
    b = x + 1.0 - a  # continued fraction of Q(a, x)
    c, d = 1.0 / _TINY, 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        step = d * c
        h *= step
        if abs(step - 1.0) < _EPS:
            break
    return math.exp(log_front) * h


def chi2_sf(q, dof):
    """Survival function ``P(χ²_dof ≥ q)`` (float64; ``q`` a number or an array).

    Raises:
        ValueError: for ``dof <= 0``.
    """
    if not dof > 0:
        raise ValueError(f"dof must be > 0, got {dof!r}")
    a = float(dof) / 2.0
    qs = np.asarray(q, np.float64)
    out = np.array([_upper_gamma(a, v / 2.0) if v == v else np.nan for v in qs.reshape(-1)])
    return out.reshape(qs.shape) if qs.ndim else out[0]


def chi2_critical(level: float, dof) -> float:
    """The ``q`` where :func:`chi2_sf` falls to ``level``: ``chi2_sf(q, dof) < level`` exactly
    when ``q > chi2_critical(level, dof)`` (the survival function decreases strictly), to
    float64 bisection accuracy."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    lo, hi = 0.0, float(dof) + 10.0 * math.sqrt(2.0 * float(dof)) + 100.0
    while chi2_sf(hi, dof) >= level:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        lo, hi = (mid, hi) if chi2_sf(mid, dof) >= level else (lo, mid)
    return hi
