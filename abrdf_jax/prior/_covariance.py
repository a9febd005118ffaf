"""The stationary part of the fused model: coordinates of a direction pair, covariance kernels,
and the hyper-parameters (:class:`FusedHyper`).

A coordinate system maps ``(wi, wv)`` to features ``(..., F)``; each feature belongs to one
width group, and the kernel sees ``r² = Σ_f ((x_f − x'_f) / ℓ_{group(f)})²``:

- ``"onion"``: the RBF's onion coordinates ``[αi, βi, αv, βv]`` (Havran et al. 2010), widths
  ``(ℓ_α, ℓ_β)`` shared by illumination and view.
- ``"halfdiff"``: Rusinkiewicz's half/difference angles as an embedding in which lobes are
  compact: ``√θh`` (the half-vector elevation warped as MERL's table is, ``ℓ_θh``),
  ``sin θh (cos 2φh, sin 2φh)`` (the half-vector azimuth, only where it means anything and
  π-periodic: ``ℓ_φh``; a large ``ℓ_φh`` is an isotropic residual), ``θd`` (``ℓ_θd``) and
  ``sin θd (cos 2φd, sin 2φd)`` (``ℓ_φd``; π-periodic as reciprocity makes it).

Kernels are functions of ``r²`` with ``k(0) = 1`` (the scale is ``σ_k²``): Gaussian and Matérn
ν = 3/2, 5/2 (Rasmussen & Williams 2006, eq. 4.17), finite with a finite gradient at ``r = 0``.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError
from .._grid import half_diff, onion_from_vector
from ._fused_settings import SCALES, WIDTH_NAMES


def _safe_r(r2):
    pos = r2 > 0
    return pos, jnp.sqrt(jnp.where(pos, r2, 1.0))


def _gaussian(r2):
    return jnp.exp(-r2)


def _matern32(r2):
    pos, r = _safe_r(r2)
    s = jnp.sqrt(3.0) * r
    return jnp.where(pos, (1.0 + s) * jnp.exp(-s), 1.0)


def _matern52(r2):
    pos, r = _safe_r(r2)
    s = jnp.sqrt(5.0) * r
    return jnp.where(pos, (1.0 + s + 5.0 / 3.0 * r2) * jnp.exp(-s), 1.0)


#: Covariance kernels of ``r²`` with ``k(0) = 1``.
COVARIANCES: dict[str, Callable] = {
    "gaussian": _gaussian,
    "matern32": _matern32,
    "matern52": _matern52,
}


def _onion(wi, wv):
    return jnp.concatenate([onion_from_vector(wi), onion_from_vector(wv)], axis=-1)


def _halfdiff(wi, wv):
    hd = half_diff(wi, wv)
    th, ph, td, pd = hd[..., 0], hd[..., 1], hd[..., 2], hd[..., 3]
    sh, sd = jnp.sin(th), jnp.sin(td)
    feats = (
        jnp.sqrt(jnp.maximum(th, 0.0) + 1e-12),
        sh * jnp.cos(2 * ph),
        sh * jnp.sin(2 * ph),
        td,
        sd * jnp.cos(2 * pd),
        sd * jnp.sin(2 * pd),
    )
    return jnp.stack(feats, axis=-1)


@dataclasses.dataclass(frozen=True)
class Coordinates:
    """``fn(wi, wv) -> (..., F)``, the width group of each feature, names of the groups."""

    fn: Callable[[Array, Array], Array]
    groups: tuple[int, ...]
    width_names: tuple[str, ...]
    default_widths: tuple[float, ...]


COORDINATES: dict[str, Coordinates] = {
    "onion": Coordinates(_onion, (0, 1, 0, 1), WIDTH_NAMES["onion"], (0.5, 0.5)),
    "halfdiff": Coordinates(
        _halfdiff, (0, 1, 1, 2, 3, 3), WIDTH_NAMES["halfdiff"], (0.1, 1, 0.5, 1)
    ),
}


def _lookup(registry, name, what):
    if name not in registry:
        raise InputError(f"{what} must be one of {', '.join(registry)}, got {name!r}")
    return registry[name]


def coordinates(name: str) -> Coordinates:
    return _lookup(COORDINATES, name, "coords")


class FusedHyper(eqx.Module):
    """Hyper-parameters of the fused model, stored as logs (every value positive, differentiable).

    Attributes:
        log_widths: ``(G,)`` logs of the kernel widths, one per width group of ``coords``.
        log_sigma_p: log of the prior's scale ``σ_p`` (1: the prior as trained).
        log_sigma_k: log of the stationary residual's scale ``σ_k``.
        log_sigma_n: log of the noise (and model error) scale ``σ_n`` in mapped space.
        coords, kernel: names in :data:`COORDINATES` and :data:`COVARIANCES` (static).
    """

    log_widths: Float[Array, " G"]
    log_sigma_p: Float[Array, ""]
    log_sigma_k: Float[Array, ""]
    log_sigma_n: Float[Array, ""]
    coords: str = eqx.field(static=True, default="halfdiff")
    kernel: str = eqx.field(static=True, default="matern52")

    def __check_init__(self):
        coordinates(self.coords)
        _lookup(COVARIANCES, self.kernel, "kernel")
        g = len(coordinates(self.coords).width_names)
        if self.log_widths.shape[-1:] != (g,):
            raise InputError(f"{self.coords} needs {g} widths, got shape {self.log_widths.shape}")

    @classmethod
    def create(
        cls,
        *,
        widths=None,
        sigma_p=1.0,
        sigma_k=0.3,
        sigma_n=0.1,
        coords="halfdiff",
        kernel="matern52",
        dtype=jnp.float32,
    ) -> "FusedHyper":
        """Hyper-parameters from positive values (``widths``: default the coordinates')."""
        widths = coordinates(coords).default_widths if widths is None else widths
        values = [np.asarray(widths, np.float64), sigma_p, sigma_k, sigma_n]
        if any(np.any(np.asarray(v) <= 0) for v in values):
            raise InputError(f"FusedHyper: widths and scales must be > 0, got {values}")
        logs = [jnp.asarray(np.log(v), dtype) for v in values]
        return cls(*logs, coords=coords, kernel=kernel)

    @classmethod
    def from_settings(cls, settings: dict, dtype=jnp.float32) -> "FusedHyper":
        """From plain settings (a prior file's ``"fused"`` member,
        :data:`~abrdf_jax.prior.FUSED_DEFAULTS`)."""
        scales = {k: settings[k] for k in SCALES}
        return cls.create(
            widths=settings["widths"],
            **scales,
            coords=settings["coords"],
            kernel=settings["kernel"],
            dtype=dtype,
        )

    @property
    def widths(self):
        return jnp.exp(self.log_widths)

    @property
    def sigma_p(self):
        return jnp.exp(self.log_sigma_p)

    @property
    def sigma_k(self):
        return jnp.exp(self.log_sigma_k)

    @property
    def sigma_n(self):
        return jnp.exp(self.log_sigma_n)

    def as_dict(self) -> dict:
        """Plain floats (for records and benchmark results)."""
        names = coordinates(self.coords).width_names
        out = {f"width_{n}": float(w) for n, w in zip(names, np.asarray(self.widths))}
        for k in ("sigma_p", "sigma_k", "sigma_n"):
            out[k] = float(getattr(self, k))
        return dict(coords=self.coords, kernel=self.kernel, **out)


def features(hyper: FusedHyper, wi, wv) -> Float[Array, "... F"]:
    """The coordinates of direction pairs scaled by their widths (``r²`` = squared distance)."""
    c = coordinates(hyper.coords)
    x = c.fn(wi, wv)
    return x / hyper.widths[np.asarray(c.groups)].astype(x.dtype)


def covariance(hyper: FusedHyper, xa, xb) -> Float[Array, "a b"]:
    """``k(xa, xb)`` of scaled features ``(a, F)``, ``(b, F)`` (unit scale)."""
    r2 = jnp.zeros((xa.shape[0], xb.shape[0]), xa.dtype)
    for f in range(xa.shape[-1]):  # direct differences: r² ≥ 0, exactly 0 on the diagonal
        d = xa[:, f, None] - xb[None, :, f]
        r2 = r2 + d * d
    return COVARIANCES[hyper.kernel](r2)
