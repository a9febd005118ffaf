"""Coordinates of a direction pair for the RBF: a registry of parameterizations.

Each entry maps ``(wi, wv)`` unit vectors ``(..., 3)`` to coordinates ``(..., d)`` in radians
(``d = 4``, or 6 for ``"onion-hd"``) and carries the kernel width used when no width was tuned
for it (:meth:`Params.default`). The four widths of :class:`~abrdf_jax.Params` scale the first
four coordinates; further coordinates take their geometric mean, unless ``Params.widths`` has
one width per coordinate (:func:`abrdf_jax._rbf_system.coordinate_widths`). To add a
parameterization, add one :class:`Parameterization` to :data:`PARAMETERIZATIONS`; its name is
then valid in ``Config(parameterization=...)``, parameter files and the command line.

``"onion-hd"`` is the onion parameterization with two coordinates of the half-vector
(Rusinkiewicz 1998) appended: ``√(θh · π/2)`` (the square-root warp of θh that MERL's tables
use, which spreads the specular peak's neighbourhood) and ``θd``, with the geometric mean of
the four onion widths as their width (the best ratio of 0.5–2 on the MERL train split, ``python
-m benchmarks.onion_hd``). A specular lobe is compact in θh, but in the onion (or spherical)
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


def _onion_hd(wi, wv, xp):
    hd = half_diff(wi, wv, xp)  # θh, θd by atan2: exact 0 at the mirror and retro pairs
    th = xp.sqrt(xp.maximum(hd[..., 0], 1e-30) * (0.5 * math.pi))  # floor: a finite gradient
    return xp.concatenate([_onion(wi, wv, xp), xp.stack([th, hd[..., 2]], axis=-1)], axis=-1)


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
