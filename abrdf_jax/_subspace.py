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

Each rule is a :class:`Rule` in :data:`RULES` with its properties beside it (``linear``: linear in
the sample values, so the compiled operator can absorb it). To add a rule, register one function
with :func:`_rule` and list its name in ``abrdf_jax._names.RULES``; an unknown name raises.
"""

import dataclasses
import functools
from typing import Callable

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._interp1d import periodic_interp
from ._names import check_registry, check_trait, lookup
from ._rules import AFFINE, combine

TWO_PI = 2.0 * jnp.pi


def _slice_at(t, y, n, tq, interp):
    """Slice value averaged over the two torus preimages ``tq`` and ``tq + π``."""
    return 0.5 * (
        periodic_interp(t, y, n, tq, interp) + periodic_interp(t, y, n, tq + jnp.pi, interp)
    )


def _masked_extreme(y, n, fn):
    valid = (jnp.arange(y.shape[0], dtype=jnp.asarray(n).dtype) < n)[:, None]
    fill = jnp.inf if fn is jnp.min else -jnp.inf
    return fn(jnp.where(valid, y, fill), axis=0, keepdims=True)


class _Slices:
    """The two slices of one pair read at the queries; each quantity computed when a rule asks."""

    def __init__(
        self,
        t_axial,
        y_axial,
        n_axial,
        t_diag,
        y_diag,
        n_diag,
        phi_i,
        phi_v,
        alpha,
        interp,
        log_eps,
    ):
        self.ta, self.ya, self.na = t_axial, y_axial, n_axial
        self.td, self.yd, self.nd = t_diag, y_diag, n_diag
        self.s, self.d = phi_i + phi_v, phi_i - phi_v
        self.alpha, self.interp, self.log_eps = alpha, interp, log_eps

    xp = jnp

    @functools.cached_property
    def amin(self):
        return _masked_extreme(self.ya, self.na, jnp.min)

    @functools.cached_property
    def amax(self):
        return _masked_extreme(self.ya, self.na, jnp.max)

    @functools.cached_property
    def dmin(self):
        return _masked_extreme(self.yd, self.nd, jnp.min)

    @functools.cached_property
    def dmax(self):
        return _masked_extreme(self.yd, self.nd, jnp.max)

    @functools.cached_property
    def a(self):
        """The axial slice at the point with the same ``s``: ``φi' = (s + α) / 2``."""
        return _slice_at(self.ta, self.ya, self.na, (self.s + self.alpha) / 2, self.interp)

    @functools.cached_property
    def b(self):
        """The diagonal slice at the point with the same ``d``: ``φv' = (2π + α − d) / 2``."""
        return _slice_at(self.td, self.yd, self.nd, (TWO_PI + self.alpha - self.d) / 2, self.interp)

    @functools.cached_property
    def c(self):
        """The value where the slices cross, (α, 0) and (α + π, π), read from both slices."""
        tc = jnp.stack([self.alpha, self.alpha + jnp.pi])
        zero = 0.0 * self.alpha
        return 0.25 * (
            jnp.sum(
                periodic_interp(self.ta, self.ya, self.na, tc, self.interp), axis=0, keepdims=True
            )
            + jnp.sum(
                periodic_interp(
                    self.td, self.yd, self.nd, jnp.stack([zero, zero + jnp.pi]), self.interp
                ),
                axis=0,
                keepdims=True,
            )
        )


@dataclasses.dataclass(frozen=True)
class Rule:
    """A subspace rule: ``fn(slices) -> (Q, C)`` and its properties.

    Attributes:
        linear: linear in the sample values (then :func:`abrdf_jax.compile_operator` folds it into
            its matrix).
        needs_axial: reads the axial slice (every rule but eq. 5).
    """

    name: str
    fn: Callable[[_Slices], Array]
    linear: bool
    needs_axial: bool
    description: str


RULES: dict[str, Rule] = {}


def _rule(name: str, *, linear: bool, needs_axial: bool = True, description: str):
    def register(fn):
        RULES[name] = Rule(name, fn, linear, needs_axial, description)
        return fn

    return register


def _affine_rule(name: str, *, linear: bool, needs_axial: bool = True, description: str):
    """Register the rule ``name`` of :data:`abrdf_jax._rules.AFFINE` (its one definition)."""
    coefficients = AFFINE[name]
    _rule(name, linear=linear, needs_axial=needs_axial, description=description)(
        lambda sl: combine(coefficients(sl), lambda: sl.a, lambda: sl.b, lambda: sl.c)
    )


_affine_rule(
    "filip2012",
    linear=False,
    description="eq. (2-4): min-max stretch of a + b to the slices' range",
)
_affine_rule("average", linear=True, description="(a + b) / 2")
_affine_rule("crossing", linear=True, description="a + b - c: reproduces both slices")


@_rule("log", linear=False, description="a * b / c: multiplicative")
def _log(sl: _Slices):
    valid_a = (jnp.arange(sl.ya.shape[0], dtype=jnp.asarray(sl.na).dtype) < sl.na)[:, None]
    valid_d = (jnp.arange(sl.yd.shape[0], dtype=jnp.asarray(sl.nd).dtype) < sl.nd)[:, None]
    total = jnp.sum(jnp.abs(jnp.where(valid_a, sl.ya, 0.0)), 0, keepdims=True) + jnp.sum(
        jnp.abs(jnp.where(valid_d, sl.yd, 0.0)), 0, keepdims=True
    )
    eps = (
        sl.log_eps * total / jnp.maximum(sl.na + sl.nd, 1).astype(total.dtype)
        + jnp.finfo(sl.yd.dtype).tiny ** 0.5
    )

    def lg(x):
        return jnp.log(jnp.maximum(x, 0.0) + eps)

    return jnp.exp(lg(sl.a) + lg(sl.b) - lg(sl.c)) - eps


_affine_rule("diagonal", linear=True, needs_axial=False, description="eq. (5), isotropic: b")


check_registry("RULES", RULES)
check_trait("LINEAR_RULES", tuple(n for n, r in RULES.items() if r.linear))


def get_rule(name: str) -> Rule:
    """The registered rule ``name``; :class:`InputError` listing the names otherwise."""
    return lookup(RULES, name, "subspace rule")


def _slices(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, *rest) -> _Slices:
    """The :class:`_Slices` of one pair, counts of at least 1 (see :func:`subspace`)."""
    na, nd = jnp.maximum(n_axial, 1), jnp.maximum(n_diag, 1)
    return _Slices(t_axial, y_axial, na, t_diag, y_diag, nd, *rest)


def subspace_terms(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, interp):
    """The slice terms ``(a, b, c)`` of :class:`_Slices` at the queries, ``(3, Q, C)``: linear in
    the slice values (the held-out errors of model selection build matrices from them,
    :mod:`abrdf_jax.select._held_out_entry`; the rules of :mod:`abrdf_jax._rules` combine them).
    A missing slice (count 0) is the caller's to handle, as :func:`subspace` does."""
    sl = _slices(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, interp, 0)
    return jnp.stack([sl.a, sl.b, jnp.broadcast_to(sl.c, sl.a.shape)])


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
    rule: str | tuple[str, ...] = "filip2012",
    interp: str = "linear",
    log_eps: float = 1e-3,
) -> Float[Array, "Q C"]:
    """Reconstruct one toroidal subspace at query azimuths from its two slices.

    Args:
        t_axial, y_axial, n_axial: the axial slice (parameter φi), padded, and its count.
        t_diag, y_diag, n_diag: the diagonal slice (parameter φv), padded, and its count.
        phi_i, phi_v: query azimuths (radians).
        alpha: slice offset α (radians).
        rule: one of :data:`RULES` (see the module docstring), or a tuple of them: then every
            rule reads the same slice interpolations and the result is ``(R, Q, C)``.
        interp: 1D slice interpolation, ``"linear"`` or ``"cubic"``.
        log_eps: ε of the ``"log"`` rule, relative to the mean absolute sample value.

    Returns:
        Reconstructed values, shape ``(Q, C)``.
    """
    rules = (rule,) if isinstance(rule, str) else tuple(rule)
    rs = [get_rule(name) for name in rules]
    # A slice that was not measured (count 0, e.g. an axial slice with too few samples of its
    # own): the rules would read padding. The pair then falls back to the slice it has, eq. (5)
    # when only the diagonal one is there (docs/stability.md). Counts of at least 1 keep every
    # branch finite, so the unused one cannot put NaN into gradients.
    has_axial, has_diag = jnp.asarray(n_axial) > 0, jnp.asarray(n_diag) > 0
    sl = _slices(
        t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, interp, log_eps
    )
    outs = []
    for r in rs:
        out = r.fn(sl)
        if r.needs_axial:
            out = jnp.where(has_axial, jnp.where(has_diag, out, sl.a), sl.b)
        outs.append(out)
    return outs[0] if isinstance(rule, str) else jnp.stack(outs)
