"""Coordinates of a direction pair for the RBF: a registry of parameterizations.

Each entry maps ``(wi, wv)`` unit vectors ``(..., 3)`` to coordinates ``(..., d)`` in radians
(``d = 4``, or 6 for ``"onion-hd"``) and carries the kernel width used when no width was tuned
for it (:meth:`Params.default`). The four widths of :class:`~abrdf_jax.Params` scale the first
four coordinates; further coordinates take their geometric mean
(:func:`abrdf_jax._rbf_system.coordinate_widths`). To add a parameterization, add one
:class:`Parameterization` to :data:`PARAMETERIZATIONS`; its name is then valid in
``Config(parameterization=...)``, parameter files and the command line.

``"onion-hd"`` is the onion parameterization with two coordinates of the half-vector
(Rusinkiewicz 1998) appended: ``√(θh · π/2)`` (the square-root warp of θh that MERL's tables
use, which spreads the specular peak's neighbourhood) and ``θd``, both weighted by
:data:`HD_WEIGHT`. A specular lobe is compact in θh, but in the onion (or spherical)
coordinates its width in ``φi − φv`` shrinks with the elevation (``θh ≈ tan θ · δ/2`` at
``δ`` from the mirror azimuth of a pair of equal elevations ``θ``: 6.5 times narrower at 75°
than at 30°): an RBF in onion coordinates alone blends lobes of different widths between the
measured rings, while the appended coordinates put the samples of a lobe close together
whatever their elevation. The onion coordinates are kept whole, so nothing of an anisotropic
material is lost. Chosen on the MERL train split (``python -m benchmarks.merl_accuracy``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Callable


from ._grid import from_vector, half_diff, onion_from_vector
from ._names import check_registry, lookup
from ._xp import namespace

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float


def _onion(wi, wv, xp):
    return xp.concatenate([onion_from_vector(wi, xp), onion_from_vector(wv, xp)], axis=-1)


#: Weight of the half-vector coordinates of ``"onion-hd"`` against the onion coordinates (their
#: kernel width is the geometric mean of the onion coordinates' widths): the best of 0.5–2 on
#: the MERL train split (``python -m benchmarks.onion_hd``, results/onion_hd.md).
HD_WEIGHT = 1.0


def _safe_norm(v, xp):
    """``|v|`` over the last axis, 0 with a zero (not NaN) gradient at ``v = 0``."""
    n2 = xp.sum(v * v, axis=-1)
    return xp.where(n2 > 0, xp.sqrt(xp.where(n2 > 0, n2, 1.0)), 0.0)


def _onion_hd(wi, wv, xp):
    s = wi + wv  # never 0 above the horizon (wi = -wv)
    h = s / xp.maximum(_safe_norm(s, xp), 1e-30)[..., None]
    # Angles by atan2 of the sine and cosine parts, accurate near 0 (arccos near 1 is not: in
    # float32 it puts the mirror pair's θh at about 3e-4, and the square root spreads that)
    th = xp.arctan2(_safe_norm(h[..., :2], xp), h[..., 2])
    td = xp.arctan2(_safe_norm(xp.cross(wi, h), xp), xp.sum(wi * h, axis=-1))
    th = xp.sqrt(xp.maximum(th, 1e-30) * (0.5 * math.pi))  # the floor: a finite gradient at 0
    return xp.concatenate([_onion(wi, wv, xp), HD_WEIGHT * xp.stack([th, td], axis=-1)], axis=-1)


def _spherical(wi, wv, xp):
    ti, pi_ = from_vector(wi, xp)
    tv, pv = from_vector(wv, xp)
    return xp.stack([ti, pi_, tv, pv], axis=-1)


@dataclasses.dataclass(frozen=True)
class Parameterization:
    """One parameterization: ``fn(wi, wv, xp) -> (..., d)`` and its fallback kernel width (radians)."""

    name: str
    fn: Callable[[Array, Array], Array]
    fallback_width: float
    description: str


PARAMETERIZATIONS: dict[str, Parameterization] = {
    p.name: p
    for p in (
        Parameterization(
            "onion", _onion, 0.6, "[αi, βi, αv, βv] (Havran et al. 2010; the paper's)"
        ),
        Parameterization("spherical", _spherical, 0.6, "[θi, φi, θv, φv]"),
        Parameterization("halfdiff", half_diff, 0.6, "[θh, φh, θd, φd] (Rusinkiewicz 1998)"),
        Parameterization(
            "onion-hd", _onion_hd, 0.6, "[αi, βi, αv, βv, √(θh π/2), θd]: onion + half-vector"
        ),
    )
}
check_registry("PARAMETERIZATIONS", PARAMETERIZATIONS)


def parameterization(name: str) -> Parameterization:
    """The registered parameterization ``name``; :class:`InputError` listing the names otherwise."""
    return lookup(PARAMETERIZATIONS, name, "parameterization")


def pair_coordinates(
    wi: Float[Array, "q 3"], wv: Float[Array, "q 3"], name: str, xp=None
) -> Float[Array, "q d"]:
    """Coordinates of direction pairs for the RBF in parameterization ``name`` (``xp``:
    ``jax.numpy`` by default, or ``numpy``): ``(q, 4)``, or ``(q, 6)`` for ``"onion-hd"``."""
    return parameterization(name).fn(wi, wv, namespace(xp))
