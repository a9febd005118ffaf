"""Coordinates of a direction pair for the RBF: a registry of parameterizations.

Each entry maps ``(wi, wv)`` unit vectors ``(..., 3)`` to four coordinates ``(..., 4)`` in radians
and carries the kernel width used when no width was tuned for it (:meth:`Params.default`). To add
a parameterization, add one :class:`Parameterization` to :data:`PARAMETERIZATIONS`; its name is
then valid in ``Config(parameterization=...)``, parameter files and the command line.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Callable


from ._grid import from_vector, half_diff, onion_from_vector
from ._names import check_registry, lookup
from ._xp import namespace

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float


def _onion(wi, wv, xp):
    return xp.concatenate([onion_from_vector(wi, xp), onion_from_vector(wv, xp)], axis=-1)


def _spherical(wi, wv, xp):
    ti, pi_ = from_vector(wi, xp)
    tv, pv = from_vector(wv, xp)
    return xp.stack([ti, pi_, tv, pv], axis=-1)


@dataclasses.dataclass(frozen=True)
class Parameterization:
    """One parameterization: ``fn(wi, wv, xp) -> (..., 4)`` and its fallback kernel width (radians)."""

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
    )
}
check_registry("PARAMETERIZATIONS", PARAMETERIZATIONS)


def parameterization(name: str) -> Parameterization:
    """The registered parameterization ``name``; :class:`InputError` listing the names otherwise."""
    return lookup(PARAMETERIZATIONS, name, "parameterization")


def pair_coordinates(
    wi: Float[Array, "q 3"], wv: Float[Array, "q 3"], name: str, xp=None
) -> Float[Array, "q 4"]:
    """Coordinates of direction pairs for the RBF in parameterization ``name`` (``xp``:
    ``jax.numpy`` by default, or ``numpy``)."""
    return parameterization(name).fn(wi, wv, namespace(xp))
