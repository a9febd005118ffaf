"""Configuration (discrete, static) and parameters (continuous, traced) of a reconstruction."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._config import (  # noqa: F401 - re-exported: the configuration's public home
    FALLBACK_REG,
    PRESETS,
    RECOMMENDED,
    TUNED_DEFAULTS,
    Config,
    default_values,
    preset,
)
from ._slices import PROTOCOL_ALPHA_DEG
from ._xp import to_device

# A Config is a compile-time constant of every jitted function: a pytree node without leaves.
jax.tree_util.register_static(Config)


def _strong_array(x):
    """``jnp.asarray`` without JAX's weak type, which is part of the compile cache key: ``Params(0.2,
    ...)`` from Python floats and ``Params.default()`` then share one compile. A host number or
    array is cast on the host, its dtype given: ``jnp.asarray`` told no dtype stages an eager
    conversion, which a cold process compiles for every shape (about 10 ms each)."""
    if isinstance(x, (np.ndarray, np.generic, float, int)):
        return to_device(x)
    x = jnp.asarray(x)  # JAX arrays, tracers, sequences of them
    return x.astype(x.dtype)


class Params(eqx.Module):
    """Continuous parameters: traced, differentiable, never a recompile.

    Attributes:
        alpha: slice offset α in radians.
        widths: ``(4,)`` RBF widths ℓ per coordinate of the parameterization (radians); the two
            half-vector coordinates of ``"onion-hd"`` take the geometric mean of the four, or
            ``(d,)``: one per coordinate (:func:`abrdf_jax._rbf_system.coordinate_widths`).
        reg: RBF regularisation λ (added to the Gram diagonal).
    """

    alpha: Float[Array, ""] = eqx.field(converter=_strong_array)
    widths: Float[Array, " w"] = eqx.field(converter=_strong_array)
    reg: Float[Array, ""] = eqx.field(converter=_strong_array)

    @classmethod
    def default(
        cls, config: Config | None = None, alpha_deg: float = PROTOCOL_ALPHA_DEG, dtype=None
    ) -> "Params":
        """The package defaults for ``config`` (α = 15°, widths and λ chosen on the train split)."""
        dt = dtype or jnp.zeros(()).dtype
        return cls(*default_values(config, alpha_deg, dt))

    @property
    def alpha_deg(self) -> float:
        return float(np.rad2deg(np.asarray(self.alpha)))

    def astype(self, dtype) -> "Params":
        """The parameters as arrays of ``dtype``."""
        return Params(
            jnp.asarray(self.alpha, dtype),
            jnp.asarray(self.widths, dtype),
            jnp.asarray(self.reg, dtype),
        )

    def with_alpha_deg(self, alpha_deg: float) -> "Params":
        """The same widths and λ at another slice offset (degrees)."""
        return Params(jnp.asarray(np.deg2rad(alpha_deg), self.alpha.dtype), self.widths, self.reg)
