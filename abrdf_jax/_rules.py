"""The subspace rules that are affine in the slice terms, as coefficients (numpy or JAX; no JAX
import): one definition read by the pipeline (:mod:`abrdf_jax._subspace`) and by the JAX-free
held-out errors of model selection (:mod:`abrdf_jax.select._held_out_entry`).

At one elevation pair every rule but ``"log"`` restores the subspace as
``B̂ = ca · a + cb · b + cc · c + const`` from the slice terms ``a``, ``b``, ``c`` of
:class:`abrdf_jax._subspace._Slices` (the axial slice at the same ``s``, the diagonal slice at the
same ``d``, the crossing value). The coefficients are numbers for the linear rules and, for
``"filip2012"``, functions of the two slices' sample extremes (one value per pair and channel), so
a fit that is linear in the samples stays linear in them once the extremes are known. A
coefficient given as the Python number ``0`` means the term is not read at all (``"diagonal"``
needs no axial slice).
"""

from __future__ import annotations

from typing import Callable

from ._names import check_registry

#: ``name -> coefficients(extremes) -> (ca, cb, cc, const)``; ``extremes`` has ``amin, amax,
#: dmin, dmax`` (the axial and diagonal slices' sample extremes, broadcastable to the terms) and
#: ``xp`` (``numpy`` or ``jax.numpy``).
AFFINE: dict[str, Callable] = {}


def _affine(name: str):
    def register(fn):
        AFFINE[name] = fn
        return fn

    return register


@_affine("filip2012")
def _filip2012(e):
    """eq. (2)–(4), our reading: ``m + (a + b − v_min) / (v_max − v_min) · (M − m)`` with
    ``m, M`` the extremes of both slices and ``v_min, v_max`` the sums of the slices' extremes
    (``m`` where the slices are constant)."""
    xp = e.xp
    m, big_m = xp.minimum(e.amin, e.dmin), xp.maximum(e.amax, e.dmax)
    lo, span = e.amin + e.dmin, (e.amax + e.dmax) - (e.amin + e.dmin)
    ok = span > 0
    scale = xp.where(ok, (big_m - m) / xp.where(ok, span, 1.0), 0.0)
    return scale, scale, 0, m - lo * scale


@_affine("average")
def _average(e):
    return 0.5, 0.5, 0, 0


@_affine("crossing")
def _crossing(e):
    return 1.0, 1.0, -1.0, 0


@_affine("diagonal")
def _diagonal(e):
    return 0, 1.0, 0, 0


check_registry("AFFINE_RULES", AFFINE)


def combine(coefficients, a: Callable, b: Callable, c: Callable, one: Callable | None = None):
    """``ca · a() + cb · b() + cc · c() + const · one()``, reading only the terms whose
    coefficient is not the number ``0`` (``a``, ``b``, ``c``, ``one``: functions that give the
    terms; without ``one`` the constant is added as it is)."""
    out = 0
    for coef, term in zip(coefficients, (a, b, c, one)):
        if not (isinstance(coef, (int, float)) and coef == 0):
            out = out + (coef if term is None else coef * term())
    return out
