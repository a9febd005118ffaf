"""A set of measured ABRDF samples: directions and linear RGB values."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._errors import InputError


class Samples(eqx.Module):
    """Measured samples in PROTOCOL.md's CSV layout, angles in degrees.

    Attributes:
        theta_i, phi_i, theta_v, phi_v: shape ``(n,)``, degrees.
        rgb: shape ``(n, 3)``, linear RGB ABRDF values (BRDF · cos θi).
    """

    theta_i: Float[Array, " n"]
    phi_i: Float[Array, " n"]
    theta_v: Float[Array, " n"]
    phi_v: Float[Array, " n"]
    rgb: Float[Array, "n 3"]

    def __check_init__(self):
        n = np.shape(self.theta_i)
        for name in ("phi_i", "theta_v", "phi_v"):
            if np.shape(getattr(self, name)) != n:
                raise InputError(f"Samples.{name} has shape {np.shape(getattr(self, name))}, expected {n}")
        if np.shape(self.rgb) != (*n, 3):
            raise InputError(f"Samples.rgb has shape {np.shape(self.rgb)}, expected {(*n, 3)}")

    def __len__(self) -> int:
        return int(np.shape(self.theta_i)[0])

    def to_numpy(self) -> "Samples":
        return Samples(*(np.asarray(x) for x in (self.theta_i, self.phi_i, self.theta_v, self.phi_v, self.rgb)))

    @staticmethod
    def concatenate(parts: "list[Samples]") -> "Samples":
        return Samples(*(jnp.concatenate([getattr(p, f) for p in parts]) for f in
                         ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")))
