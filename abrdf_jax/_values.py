"""Value spaces: what the interpolation sees of the sample values, and the way back (one copy).

- ``"linear"``: the values themselves (the paper).
- ``"log"``: the RBF interpolates ``ln(max(x, 0) + ε)`` of the *subspace values* (after the rule).
- ``"logsamples"``: the log is taken of the *samples*, before slice interpolation and the rule;
  with a linear rule the whole map is then ``exp(M · ln(y + ε)) − ε`` (:mod:`abrdf_jax._operator`).

``ε = log_eps · mean |y|`` per channel over the valid samples (plus ``sqrt(tiny)`` so that it is
never zero). Every step ends with the clamp at 0 (an ABRDF is non-negative). The pipeline, the
compiled operator and the held-out errors of model selection all call these functions.
"""

import dataclasses

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._measurements import Measurements
from ._names import check_registry, check_trait, lookup


@dataclasses.dataclass(frozen=True)
class ValueSpace:
    """Where the log is taken: of the samples (``log_samples``) or of the subspace values."""

    name: str
    log_samples: bool
    log_subspace: bool

    @property
    def is_log(self) -> bool:
        return self.log_samples or self.log_subspace

    def eps(self, meas: Measurements, log_eps: float):
        """ε of a measurement (``None`` in linear space)."""
        return measurement_eps(meas, log_eps) if self.is_log else None

    def encode_samples(self, meas: Measurements, eps) -> Measurements:
        """The measurement as the slice interpolation sees it (log of the valid samples, or as is)."""
        if not self.log_samples:
            return meas
        return meas.replace(y=jnp.where(meas.mask[..., None], log_values(meas.y, eps), 0.0))

    def encode_subspace(self, vals, eps):
        """Subspace values as the RBF sees them."""
        return log_values(vals, eps) if self.log_subspace else vals

    def decode(self, out, eps):
        """RBF output back to ABRDF values, clamped at 0."""
        if self.is_log:
            out = jnp.exp(out) - jnp.broadcast_to(eps, out.shape)
        return jnp.maximum(out, 0.0)


VALUE_SPACES: dict[str, ValueSpace] = {
    v.name: v
    for v in (
        ValueSpace("linear", False, False),
        ValueSpace("log", False, True),
        ValueSpace("logsamples", True, False),
    )
}
check_registry("VALUE_SPACES", VALUE_SPACES)
check_trait("LOG_SUBSPACE", tuple(n for n, v in VALUE_SPACES.items() if v.log_subspace))
check_trait("LOG_SAMPLES", tuple(n for n, v in VALUE_SPACES.items() if v.log_samples))


def value_space(name: str) -> ValueSpace:
    """The registered value space ``name``; :class:`InputError` listing the names otherwise."""
    return lookup(VALUE_SPACES, name, "value space")


def value_eps(mean_abs, log_eps: float, dtype):
    """ε of the log value spaces: ``log_eps`` times the mean absolute sample, per channel."""
    return log_eps * mean_abs + jnp.finfo(dtype).tiny ** 0.5


def measurement_eps(meas: Measurements, log_eps: float) -> Float[Array, " C"]:
    """ε of a measurement: :func:`value_eps` of the mean absolute valid sample, per channel."""
    total = jnp.sum(jnp.where(meas.mask[..., None], jnp.abs(meas.y), 0.0), axis=(-3, -2))
    mean = total / jnp.maximum(jnp.sum(meas.count, axis=-1), 1)[..., None].astype(total.dtype)
    return value_eps(mean, log_eps, meas.y.dtype)


def log_values(x, eps):
    """``ln(max(x, 0) + ε)``: the values the RBF sees in the log value spaces."""
    return jnp.log(jnp.maximum(x, 0.0) + jnp.broadcast_to(eps, x.shape))  # eps: (C,) or (B, 1, C)
