"""Measured data: flat samples (:class:`Samples`) and samples grouped into slices (:class:`Measurements`).

A grouped measurement is a fixed-shape pytree: slice ``2p`` is the axial slice of elevation pair ``p``
and ``2p + 1`` its diagonal slice; each slice holds up to ``nmax`` samples sorted by angle, padded,
with a count (zero for an unmeasured slice). ``Measurements.mask`` is the one place that says which
entries are samples and which are padding.
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._errors import InputError
from ._finite import check_concrete, concrete
from ._slices import KINDS, PROTOCOL_ALPHA_DEG, slice_angles


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
                raise InputError(
                    f"Samples.{name} has shape {np.shape(getattr(self, name))}, expected {n}"
                )
        if np.shape(self.rgb) != (*n, 3):
            raise InputError(f"Samples.rgb has shape {np.shape(self.rgb)}, expected {(*n, 3)}")
        for name in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb"):
            check_concrete(getattr(self, name), f"Samples.{name}")

    def __len__(self) -> int:
        return int(np.shape(self.theta_i)[0])

    def to_numpy(self) -> "Samples":
        return Samples(
            *(np.asarray(x) for x in (self.theta_i, self.phi_i, self.theta_v, self.phi_v, self.rgb))
        )

    @staticmethod
    def concatenate(parts: "list[Samples]") -> "Samples":
        return Samples(
            *(
                jnp.concatenate([getattr(p, f) for p in parts])
                for f in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")
            )
        )


class Measurements(eqx.Module):
    """Samples grouped into slices, as a fixed-shape pytree.

    Attributes:
        t: ``(S, nmax)`` slice parameter (radians, sorted, in [0, 2π)), padding past ``count``.
        y: ``(S, nmax, 3)`` linear RGB values (padding is zero).
        count: ``(S,)`` number of valid samples per slice (0: slice not measured).
        pairs: static tuple of the ``P = S / 2`` elevation pairs ``(θi, θv)`` in degrees.
        has_axial: static; whether any axial slice was measured (decides the budget).
        centre_azimuths: static; RBF centre azimuths per ring where the UBO ring has fewer
            (``None``: the UBO rings'; a dense capture gets more, see ``abrdf_jax._grouping``).
    """

    t: Float[Array, "S nmax"]
    y: Float[Array, "S nmax 3"]
    count: Int[Array, " S"]
    pairs: tuple = eqx.field(static=True)
    has_axial: bool = eqx.field(static=True)
    centre_azimuths: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        # Concrete values only (inside a transformation they are tracers; the CLI and the
        # readers check files before): finite slices, counts in [0, nmax].
        check_concrete(self.t, "Measurements.t")
        check_concrete(self.y, "Measurements.y")
        count = concrete(self.count)
        nmax = np.shape(self.t)[-1] if np.ndim(self.t) else 0
        if count is not None and count.size and (count.min() < 0 or count.max() > nmax):
            raise InputError(
                f"Measurements.count must lie in [0, {nmax}] (the slices' length), got values "
                f"from {int(count.min())} to {int(count.max())}"
            )

    @property
    def n_samples(self) -> int:
        return int(np.sum(np.asarray(self.count)))

    @property
    def mask(self):
        """``(..., S, nmax)`` bool: which entries are samples (the rest is padding)."""
        index = jnp.broadcast_to(jnp.arange(self.t.shape[-1], dtype=self.count.dtype), self.t.shape)
        return index < self.count[..., None]

    def slice_cos_view(self) -> np.ndarray:
        """``cos θv`` of each slice, ``(S,)`` float64 (host): slice ``s`` lies on the view ring of
        ``pairs[s // 2]``, so every sample of it shares one ``θv``."""
        tv = np.repeat(np.asarray([p[1] for p in self.pairs], np.float64), 2)
        return np.cos(np.deg2rad(tv))

    def replace(self, **fields) -> "Measurements":
        """A copy with some fields replaced (``t``, ``y``, ``count``, ``pairs``, ``has_axial``)."""
        unknown = set(fields) - {"t", "y", "count", "pairs", "has_axial", "centre_azimuths"}
        if unknown:
            raise InputError(f"Measurements has no field(s) {sorted(unknown)}")
        return dataclasses.replace(self, **fields)

    def astype(self, dtype) -> "Measurements":
        """The measurement with ``t`` and ``y`` in ``dtype`` (counts stay integers)."""
        return self.replace(t=jnp.asarray(self.t, dtype), y=jnp.asarray(self.y, dtype))

    def select_slices(self, pair_indices) -> "Measurements":
        """The measurement restricted to some elevation pairs (both slices of each)."""
        rows = np.asarray([r for p in pair_indices for r in (2 * p, 2 * p + 1)])
        return self.replace(
            t=self.t[..., rows, :],
            y=self.y[..., rows, :, :],
            count=self.count[..., rows],
            pairs=tuple(self.pairs[p] for p in pair_indices),
        )

    def to_samples(self, alpha_deg: float = PROTOCOL_ALPHA_DEG) -> Samples:
        """Flatten to a :class:`Samples` list (numpy), e.g. to write a measurement CSV."""
        t = np.asarray(self.t)
        y = np.asarray(self.y)
        cnt = np.asarray(self.count)
        alpha = np.deg2rad(alpha_deg)
        cols = [[], [], [], [], []]
        for s in range(t.shape[0]):
            k = int(cnt[s])
            if k == 0:
                continue
            ti, tv = self.pairs[s // 2]
            pi_, pv = slice_angles(KINDS[s % 2], t[s, :k], alpha)
            cols[0].append(np.full(k, ti))
            cols[1].append(np.rad2deg(np.asarray(pi_)))
            cols[2].append(np.full(k, tv))
            cols[3].append(np.rad2deg(np.asarray(pv)))
            cols[4].append(y[s, :k])
        return Samples(*(np.concatenate(c) for c in cols))


def stack_measurements(items: list[Measurements]) -> Measurements:
    """Stack measurements of one layout along a new leading (material) axis, padding slices."""
    if not items:
        raise ValueError("no measurements to stack")
    pairs, az = items[0].pairs, items[0].centre_azimuths
    for m in items:
        if m.pairs != pairs:
            raise InputError("cannot stack measurements of different elevation pairs")
        if m.centre_azimuths != az:
            raise InputError(
                "cannot stack measurements of different RBF centre layouts (dense and sparse "
                "captures); reconstruct them in separate batches"
            )
    nmax = max(m.t.shape[1] for m in items)

    def pad(x, axis_len):
        w = [(0, 0)] * x.ndim
        w[1] = (0, axis_len - x.shape[1])
        return jnp.pad(x, w)

    return Measurements(
        jnp.stack([pad(m.t, nmax) for m in items]),
        jnp.stack([pad(m.y, nmax) for m in items]),
        jnp.stack([m.count for m in items]),
        pairs,
        any(m.has_axial for m in items),
        az,
    )
