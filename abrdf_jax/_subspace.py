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

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Callable

import numpy as np

from ._grid import centre_layout
from ._interp1d import periodic_interp
from ._names import check_registry, check_trait, lookup
from ._rules import AFFINE, combine
from ._xp import namespace

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float

TWO_PI = 2.0 * np.pi


def _slice_at(t, y, n, tq, interp, xp):
    """Slice value averaged over the two torus preimages ``tq`` and ``tq + π`` (one call: the
    numpy path's cost is per call, the values are the same)."""
    q = tq.shape[0]
    both = periodic_interp(t, y, n, xp.concatenate([tq, tq + np.pi]), interp, xp)
    return 0.5 * (both[:q] + both[q:])


def _masked_extreme(y, n, lowest: bool, xp):
    valid = (xp.arange(y.shape[0], dtype=xp.asarray(n).dtype) < n)[:, None]
    fn, fill = (xp.min, np.inf) if lowest else (xp.max, -np.inf)
    return fn(xp.where(valid, y, fill), axis=0, keepdims=True)


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
        xp,
    ):
        self.ta, self.ya, self.na = t_axial, y_axial, n_axial
        self.td, self.yd, self.nd = t_diag, y_diag, n_diag
        self.s, self.d = phi_i + phi_v, phi_i - phi_v
        self.alpha, self.interp, self.log_eps, self.xp = alpha, interp, log_eps, xp

    @functools.cached_property
    def amin(self):
        return _masked_extreme(self.ya, self.na, True, self.xp)

    @functools.cached_property
    def amax(self):
        return _masked_extreme(self.ya, self.na, False, self.xp)

    @functools.cached_property
    def dmin(self):
        return _masked_extreme(self.yd, self.nd, True, self.xp)

    @functools.cached_property
    def dmax(self):
        return _masked_extreme(self.yd, self.nd, False, self.xp)

    @functools.cached_property
    def a(self):
        """The axial slice at the point with the same ``s``: ``φi' = (s + α) / 2``."""
        tq = (self.s + self.alpha) / 2
        return _slice_at(self.ta, self.ya, self.na, tq, self.interp, self.xp)

    @functools.cached_property
    def b(self):
        """The diagonal slice at the point with the same ``d``: ``φv' = (2π + α − d) / 2``."""
        tq = (TWO_PI + self.alpha - self.d) / 2
        return _slice_at(self.td, self.yd, self.nd, tq, self.interp, self.xp)

    @functools.cached_property
    def c(self):
        """The value where the slices cross, (α, 0) and (α + π, π), read from both slices."""
        xp = self.xp
        tc = xp.stack([self.alpha, self.alpha + np.pi])
        zero = 0.0 * self.alpha
        axial = periodic_interp(self.ta, self.ya, self.na, tc, self.interp, xp)
        diag = periodic_interp(
            self.td, self.yd, self.nd, xp.stack([zero, zero + np.pi]), self.interp, xp
        )
        return 0.25 * (xp.sum(axial, axis=0, keepdims=True) + xp.sum(diag, axis=0, keepdims=True))


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
    xp = sl.xp
    valid_a = (xp.arange(sl.ya.shape[0], dtype=xp.asarray(sl.na).dtype) < sl.na)[:, None]
    valid_d = (xp.arange(sl.yd.shape[0], dtype=xp.asarray(sl.nd).dtype) < sl.nd)[:, None]
    total = xp.sum(xp.abs(xp.where(valid_a, sl.ya, 0.0)), 0, keepdims=True) + xp.sum(
        xp.abs(xp.where(valid_d, sl.yd, 0.0)), 0, keepdims=True
    )
    eps = (
        sl.log_eps * total / xp.maximum(sl.na + sl.nd, 1).astype(total.dtype)
        + xp.finfo(sl.yd.dtype).tiny ** 0.5
    )

    def lg(x):
        return xp.log(xp.maximum(x, 0.0) + eps)

    return xp.exp(lg(sl.a) + lg(sl.b) - lg(sl.c)) - eps


_affine_rule("diagonal", linear=True, needs_axial=False, description="eq. (5), isotropic: b")


check_registry("RULES", RULES)
check_trait("LINEAR_RULES", tuple(n for n, r in RULES.items() if r.linear))


def get_rule(name: str) -> Rule:
    """The registered rule ``name``; :class:`InputError` listing the names otherwise."""
    return lookup(RULES, name, "subspace rule")


def _slices(t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, *rest, xp) -> _Slices:
    """The :class:`_Slices` of one pair, counts of at least 1 (see :func:`subspace`)."""
    na, nd = xp.maximum(n_axial, 1), xp.maximum(n_diag, 1)
    return _Slices(t_axial, y_axial, na, t_diag, y_diag, nd, *rest, xp)


def subspace_terms(
    t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, interp, xp=None
):
    """The slice terms ``(a, b, c)`` of :class:`_Slices` at the queries, ``(3, Q, C)``: linear in
    the slice values (the held-out errors of model selection build matrices from them,
    :mod:`abrdf_jax.select._held_out_entry`; the rules of :mod:`abrdf_jax._rules` combine them).
    A missing slice (count 0) is the caller's to handle, as :func:`subspace` does."""
    xp = namespace(xp)
    sl = _slices(
        t_axial, y_axial, n_axial, t_diag, y_diag, n_diag, phi_i, phi_v, alpha, interp, 0, xp=xp
    )
    return xp.stack([sl.a, sl.b, xp.broadcast_to(sl.c, sl.a.shape)])


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
    xp=None,
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
        xp: ``jax.numpy`` (default) or ``numpy`` (the JAX-free operator build).

    Returns:
        Reconstructed values, shape ``(Q, C)``.
    """
    rules = (rule,) if isinstance(rule, str) else tuple(rule)
    rs = [get_rule(name) for name in rules]
    # A slice that was not measured (count 0, e.g. an axial slice with too few samples of its
    # own): the rules would read padding. The pair then falls back to the slice it has, eq. (5)
    # when only the diagonal one is there (docs/stability.md). Counts of at least 1 keep every
    # branch finite, so the unused one cannot put NaN into gradients.
    xp = namespace(xp)
    has_axial, has_diag = xp.asarray(n_axial) > 0, xp.asarray(n_diag) > 0
    slices = (t_axial, y_axial, n_axial, t_diag, y_diag, n_diag)
    sl = _slices(*slices, phi_i, phi_v, alpha, interp, log_eps, xp=xp)
    outs = []
    for r in rs:
        out = r.fn(sl)
        if r.needs_axial:
            out = xp.where(has_axial, xp.where(has_diag, out, sl.a), sl.b)
        outs.append(out)
    return outs[0] if isinstance(rule, str) else xp.stack(outs)


def centre_subspaces(
    t, y, count, pairs, azimuths, alpha, rule, interp: str, terms: bool = False, xp=None
):
    """The restored subspaces of every pair at its RBF centres (``centre_layout`` order),
    ``(n, C)``, from padded slices ``t`` ``(S, nmax)``, ``y`` ``(S, nmax, C)`` and ``count``
    ``(S,)`` (axial and diagonal slice of pair ``p`` at rows ``2p``, ``2p + 1``). ``rule``: a
    name, or a tuple (then ``(R, n, C)``); ``terms``: the slice terms instead, ``(3, n, C)``
    (:func:`subspace_terms`). ``xp``: ``jax.numpy`` (default) or ``numpy``."""
    xp = namespace(xp)
    vals = []
    for p, (pi_, pv) in enumerate(centre_layout(pairs, azimuths)):
        pair = (
            t[2 * p], y[2 * p], count[2 * p], t[2 * p + 1], y[2 * p + 1], count[2 * p + 1],
            xp.asarray(np.deg2rad(pi_), y.dtype), xp.asarray(np.deg2rad(pv), y.dtype), alpha,
        )  # fmt: skip
        if terms:
            vals.append(subspace_terms(*pair, interp, xp=xp))
        else:
            vals.append(subspace(*pair, rule=rule, interp=interp, xp=xp))
    return xp.concatenate(vals, axis=-2)
