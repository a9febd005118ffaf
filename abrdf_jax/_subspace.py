"""Toroidal subspace reconstruction from two slices (Filip 2012, eq. 2–5).

At one elevation pair the ABRDF is a function on the torus ``(φi, φv)``. In coordinates rotated by
π/4 (eq. 3), ``s = φi + φv`` runs along the specular highlights and ``d = φi − φv`` across them.
The axial slice (``d = α``) records the variation along ``s``, the diagonal slice (``s = α`` mod 2π)
the variation along ``d``. A point ``(φi, φv)`` takes

- ``a = s_A`` at the axial point with the same ``s``: ``φi' = (s + α) / 2``;
- ``b = s_D`` at the diagonal point with the same ``d``: ``φv' = (2π + α − d) / 2``.

On a torus each of these has two solutions, ``φ'`` and ``φ' + π`` (the slices cross twice, at
``(α, 0)`` and ``(α + π, π)``); we average the slice over both. For any additively separable
``B = f(s) + g(d)`` both solutions carry the same value, so nothing is lost there; for data with the
usual 180° rotational symmetry of anisotropic surfaces they agree too.

Rules (``rule=``):

- ``"diagonal"`` — eq. (5), isotropic data: ``B̂ = b``.
- ``"filip2012"`` — eq. (2)–(4), our reading: the sum ``v = a + b`` is min–max stretched to the
  slices' dynamic range, ``B̂ = m + (v − v_min) / (v_max − v_min) · (M − m)`` with
  ``m, M = min, max(s_A ∪ s_D)`` and ``v_min = min s_A + min s_D``, ``v_max = max s_A + max s_D``
  (the exact extremes of ``v`` over the torus, since ``s`` and ``d`` vary independently). Eq. (4)
  as printed multiplies the raw sum by ``M − m``, which only makes sense for ``v`` normalised to
  [0, 1]; this is that normalisation. For isotropic data (constant axial slice inside the diagonal
  slice's range) it reduces to eq. (5) exactly.
- ``"average"`` — the other reading of eq. (4): ``B̂ = (a + b) / 2``.
- ``"crossing"`` — reproduces both slices exactly: ``B̂ = a + b − c`` with ``c`` the value where the
  slices cross (mean of the two crossings, read from both slices). Exact for ``f(s) + g(d)``.
- ``"log"`` — multiplicative (log-additive) variant for reflectance: ``B̂ = a · b / c``, computed
  as ``exp(ln(a+ε) + ln(b+ε) − ln(c+ε)) − ε``; exact for ``f(s) · g(d)`` (up to ε).

All rules except ``"filip2012"`` and ``"log"`` are linear in the sample values.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._interp1d import periodic_interp

RULES = ("filip2012", "average", "crossing", "log", "diagonal")
TWO_PI = 2.0 * jnp.pi


def _slice_at(t, y, n, tq, interp):
    """Slice value averaged over the two torus preimages ``tq`` and ``tq + π``."""
    return 0.5 * (periodic_interp(t, y, n, tq, interp) + periodic_interp(t, y, n, tq + jnp.pi, interp))


def _masked_extreme(y, n, fn):
    valid = (jnp.arange(y.shape[0]) < n)[:, None]
    fill = jnp.inf if fn is jnp.min else -jnp.inf
    return fn(jnp.where(valid, y, fill), axis=0)


def subspace(
    t_axial: Float[Array, " nmax"],
    y_axial: Float[Array, "nmax C"],
    n_axial,
    t_diag: Float[Array, " nmax"],
    y_diag: Float[Array, "nmax C"],
    n_diag,
    phi_i: Float[Array, " Q"],
    phi_v: Float[Array, " Q"],
    alpha: Float[Array, ""],
    rule: str = "filip2012",
    interp: str = "linear",
    log_eps: float = 1e-3,
) -> Float[Array, "Q C"]:
    """Reconstruct one toroidal subspace at query azimuths from its two slices.

    Args:
        t_axial, y_axial, n_axial: the axial slice (parameter φi), padded, and its count.
        t_diag, y_diag, n_diag: the diagonal slice (parameter φv), padded, and its count.
        phi_i, phi_v: query azimuths (radians).
        alpha: slice offset α (radians).
        rule: one of :data:`RULES` (see the module docstring).
        interp: 1D slice interpolation, ``"linear"`` or ``"cubic"``.
        log_eps: ε of the ``"log"`` rule, relative to the mean absolute sample value.

    Returns:
        Reconstructed values, shape ``(Q, C)``.
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    # A slice that was not measured (count 0, e.g. an axial slice with too few samples of its
    # own): the rules would read padding. The pair then falls back to the slice it has, eq. (5)
    # when only the diagonal one is there (docs/stability.md). Counts of at least 1 keep every
    # branch finite, so the unused one cannot put NaN into gradients.
    has_axial, has_diag = jnp.asarray(n_axial) > 0, jnp.asarray(n_diag) > 0
    n_axial, n_diag = jnp.maximum(n_axial, 1), jnp.maximum(n_diag, 1)
    out, a, b = _rule(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, rule, interp, log_eps)
    if rule == "diagonal":
        return out
    return jnp.where(has_axial, jnp.where(has_diag, out, a), b)


def _rule(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, rule, interp, log_eps):
    """The rule's value and the two slices read at the queries, ``(out, a, b)``."""
    s = phi_i + phi_v
    d = phi_i - phi_v
    b = _slice_at(t_diag, y_diag, n_diag, (TWO_PI + alpha - d) / 2, interp)
    if rule == "diagonal":
        return b, b, b
    a = _slice_at(t_axial, y_axial, n_axial, (s + alpha) / 2, interp)
    if rule == "average":
        return 0.5 * (a + b), a, b
    if rule == "filip2012":
        amin, amax = _masked_extreme(y_axial, n_axial, jnp.min), _masked_extreme(y_axial, n_axial, jnp.max)
        dmin, dmax = _masked_extreme(y_diag, n_diag, jnp.min), _masked_extreme(y_diag, n_diag, jnp.max)
        m, big_m = jnp.minimum(amin, dmin), jnp.maximum(amax, dmax)
        lo, hi = amin + dmin, amax + dmax
        span = hi - lo
        ok = span > 0
        u = jnp.where(ok, (a + b - lo) / jnp.where(ok, span, 1.0), 0.0)
        return m + u * (big_m - m), a, b
    # The crossings (α, 0) and (α + π, π), read from both slices.
    tc = jnp.stack([alpha, alpha + jnp.pi])
    c = 0.25 * (
        jnp.sum(periodic_interp(t_axial, y_axial, n_axial, tc, interp), axis=0)
        + jnp.sum(periodic_interp(t_diag, y_diag, n_diag, jnp.stack([0.0 * alpha, 0.0 * alpha + jnp.pi]), interp), axis=0)
    )
    if rule == "crossing":
        return a + b - c, a, b
    # "log": multiplicative.
    valid_a = (jnp.arange(y_axial.shape[0]) < n_axial)[:, None]
    valid_d = (jnp.arange(y_diag.shape[0]) < n_diag)[:, None]
    scale = (jnp.sum(jnp.abs(jnp.where(valid_a, y_axial, 0.0)), 0) + jnp.sum(jnp.abs(jnp.where(valid_d, y_diag, 0.0)), 0)) / jnp.maximum(n_axial + n_diag, 1)
    eps = log_eps * scale + jnp.finfo(y_diag.dtype).tiny ** 0.5

    def lg(x):
        return jnp.log(jnp.maximum(x, 0.0) + eps)

    return jnp.exp(lg(a) + lg(b) - lg(c)) - eps, a, b
