"""Coordinates of a direction pair for the RBF: a registry of parameterizations.

Each entry maps ``(wi, wv)`` unit vectors ``(..., 3)`` to four coordinates ``(..., 4)`` in radians
and carries the kernel width used when no width was tuned for it (:meth:`Params.default`). To add
a parameterization, add one :class:`Parameterization` to :data:`PARAMETERIZATIONS`; its name is
then valid in ``Config(parameterization=...)``, parameter files and the command line.
"""

import dataclasses
from typing import Callable

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._grid import from_vector, half_diff, onion_from_vector
from ._names import check_registry, lookup


def _onion(wi, wv):
    return jnp.concatenate([onion_from_vector(wi), onion_from_vector(wv)], axis=-1)


def _spherical(wi, wv):
    ti, pi_ = from_vector(wi)
    tv, pv = from_vector(wv)
    return jnp.stack([ti, pi_, tv, pv], axis=-1)


@dataclasses.dataclass(frozen=True)
class Parameterization:
    """One parameterization: ``fn(wi, wv) -> (..., 4)`` and its fallback kernel width (radians)."""

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
    wi: Float[Array, "q 3"], wv: Float[Array, "q 3"], name: str
) -> Float[Array, "q 4"]:
    """Coordinates of direction pairs for the RBF in parameterization ``name``."""
    return parameterization(name).fn(wi, wv)
