"""A procedural, periodic height field with horizon maps, and smooth noise fields.

The surface is a unit patch ``[0, 1)²`` (periodic in both axes, so it tiles); a BTF of ``N × N``
texels samples it at the texel centres ``((j + ½)/N, (i + ½)/N)``, so that every size shows the
same surface at a different resolution. Heights are in patch units: slopes, and therefore
shadows, do not depend on ``N``.

The height is a sum of analytic features at a few scales, all periodic:

- Fourier waves ``a cos(2π k·x + φ)`` with integer wave vectors ``k`` (rolling relief and fine
  roughness, amplitudes falling as ``|k|^-1.5``);
- Gaussian bumps and pits at three radii (stones, rivets, dents), height proportional to radius;
- families of parallel grooves ``-d exp(-(frac(k·x + φ) - ½)² / 2w²)`` (scratches, weave ribs).

The whole field is scaled so that its RMS slope is :data:`RMS_SLOPE`. Shadows and masking come
from *horizon maps* (Max, "Horizon mapping: shadows for bump-mapped surfaces", The Visual Computer
4(2), 1988; Sloan & Cohen, "Interactive horizon mapping", EGWR 2000): for each texel and each of
``K`` azimuths, the elevation of the highest point seen along that azimuth, found by marching
``S`` steps over a raster of the field with bilinear, periodic look-ups.
"""

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: RMS slope of the calibrated height field (about 27°; grazing light is often shadowed).
RMS_SLOPE = 0.5
#: Azimuths of a horizon map and ray-march steps per azimuth.
N_AZIMUTHS = 32
N_STEPS = 24
#: Farthest point a horizon ray looks at, in patch units.
HORIZON_REACH = 0.25
#: Raster resolution of the height field used by the horizon march (at least this, or 2 N).
MIN_RASTER = 256

_F32 = jnp.float32


def _integer_vectors(rng: np.random.Generator, n: int, kmin: float, kmax: float) -> np.ndarray:
    """``n`` random integer wave vectors with ``kmin <= |k| <= kmax`` (periodic on the patch)."""
    out = []
    while len(out) < n:
        k = rng.integers(-int(kmax), int(kmax) + 1, size=2)
        if kmin <= np.hypot(*k) <= kmax:
            out.append(k)
    return np.asarray(out, np.float64)


class FourierField(eqx.Module):
    """A smooth periodic random field of unit variance: ``Σ a cos(2π k·x + φ)``."""

    k: Float[Array, "F 2"]
    amp: Float[Array, " F"]
    phase: Float[Array, " F"]

    @classmethod
    def random(cls, rng: np.random.Generator, n: int = 12, kmax: float = 5.0, decay: float = 1.0):
        k = _integer_vectors(rng, n, 1.0, kmax)
        amp = np.hypot(k[:, 0], k[:, 1]) ** -decay
        amp = amp / np.sqrt(np.sum(amp**2) / 2)  # unit variance
        phase = rng.uniform(0, 2 * np.pi, n)
        return cls(jnp.asarray(k, _F32), jnp.asarray(amp, _F32), jnp.asarray(phase, _F32))

    def __call__(self, xy: Float[Array, "... 2"]) -> Float[Array, "..."]:
        arg = 2 * jnp.pi * (xy @ self.k.T) + self.phase
        return jnp.sum(self.amp * jnp.cos(arg), axis=-1)


class Surface(eqx.Module):
    """The height field ``h(x, y)`` of the unit patch (see the module docstring).

    Attributes:
        waves: the Fourier relief (scaled by ``wave_scale``).
        bump_c, bump_r, bump_a: bump centres ``(B, 2)``, radii and signed heights ``(B,)``.
        groove_k, groove_phase, groove_width, groove_depth: groove families ``(G, 2)``, ``(G,)``.
        scale: overall factor that sets the RMS slope to :data:`RMS_SLOPE`.
    """

    waves: FourierField
    wave_scale: Float[Array, ""]
    bump_c: Float[Array, "B 2"]
    bump_r: Float[Array, " B"]
    bump_a: Float[Array, " B"]
    groove_k: Float[Array, "G 2"]
    groove_phase: Float[Array, " G"]
    groove_width: Float[Array, " G"]
    groove_depth: Float[Array, " G"]
    scale: Float[Array, ""]

    def __call__(self, xy: Float[Array, "... 2"]) -> Float[Array, "..."]:
        """Height at patch coordinates ``xy`` (any real values; the field is periodic)."""
        h = self.wave_scale * self.waves(xy)
        d = xy[..., None, :] - self.bump_c  # (..., B, 2)
        d = d - jnp.round(d)  # nearest periodic image
        r2 = jnp.sum(d * d, axis=-1)
        h = h + jnp.sum(self.bump_a * jnp.exp(-r2 / (2 * self.bump_r**2)), axis=-1)
        s = xy @ self.groove_k.T + self.groove_phase
        s = s - jnp.floor(s) - 0.5
        h = h - jnp.sum(self.groove_depth * jnp.exp(-(s**2) / (2 * self.groove_width**2)), axis=-1)
        return self.scale * h

    def gradient(self, xy: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
        """``∇h`` at ``xy`` (exact, by automatic differentiation of the analytic field)."""
        return jax.vmap(jax.grad(lambda p: self(p)))(xy)

    def normals(self, xy: Float[Array, "n 2"]) -> Float[Array, "n 3"]:
        """Unit surface normals ``normalize(-∂h/∂x, -∂h/∂y, 1)`` at ``xy``."""
        g = self.gradient(xy)
        n = jnp.concatenate([-g, jnp.ones_like(g[:, :1])], axis=-1)
        return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def make_surface(rng: np.random.Generator) -> Surface:
    """A random surface: waves, bumps at three scales, two groove families; RMS slope calibrated."""
    waves = FourierField.random(rng, n=24, kmax=12.0, decay=1.5)
    centres, radii, heights = [], [], []
    for count, (rlo, rhi) in ((5, (0.07, 0.11)), (14, (0.03, 0.05)), (36, (0.012, 0.02))):
        centres.append(rng.uniform(0, 1, (count, 2)))
        r = rng.uniform(rlo, rhi, count)
        sign = np.where(rng.uniform(0, 1, count) < 0.8, 1.0, -1.0)  # mostly bumps, some pits
        radii.append(r)
        heights.append(sign * r * rng.uniform(0.6, 1.2, count))
    gk = _integer_vectors(rng, 2, 4.0, 10.0)
    gw = rng.uniform(0.06, 0.14, 2)
    gd = rng.uniform(1.0, 1.6, 2) * gw / np.hypot(gk[:, 0], gk[:, 1])
    f = lambda a: jnp.asarray(a, _F32)  # noqa: E731
    bumps = [f(np.concatenate(x)) for x in (centres, radii, heights)]
    surf = Surface(waves, f(0.02), *bumps, f(gk), f(rng.uniform(0, 1, 2)), f(gw), f(gd), f(1.0))
    # Calibrate: RMS slope over a 128² grid of the patch.
    g = np.linspace(0, 1, 128, endpoint=False) + 0.5 / 128
    xy = jnp.asarray(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), _F32)
    rms = float(_rms_slope(surf, xy))
    return eqx.tree_at(lambda s: s.scale, surf, f(RMS_SLOPE / max(rms, 1e-6)))


@jax.jit
def _rms_slope(surface: Surface, xy):
    return jnp.sqrt(jnp.mean(jnp.sum(surface.gradient(xy) ** 2, axis=-1)))


@partial(jax.jit, static_argnums=1)
def raster(surface: Surface, resolution: int) -> Float[Array, "R R"]:
    """Heights at the raster points ``(j / R, i / R)``; row ``i`` is ``y``, column ``j`` is ``x``."""
    g = jnp.arange(resolution, dtype=_F32) / resolution
    xy = jnp.stack(jnp.meshgrid(g, g), -1).reshape(-1, 2)
    return jax.lax.map(surface, xy.reshape(resolution, resolution, 2)).reshape(
        resolution, resolution
    )


def bilinear(grid: Float[Array, "R R"], xy: Float[Array, "... 2"]) -> Float[Array, "..."]:
    """Periodic bilinear look-up of a raster made by :func:`raster` at patch coordinates ``xy``."""
    r = grid.shape[0]
    u = xy[..., 0] * r
    v = xy[..., 1] * r
    j0, i0 = jnp.floor(u), jnp.floor(v)
    a, b = u - j0, v - i0
    j0 = j0.astype(jnp.int32) % r
    i0 = i0.astype(jnp.int32) % r
    j1, i1 = (j0 + 1) % r, (i0 + 1) % r
    top = (1 - a) * grid[i0, j0] + a * grid[i0, j1]
    bot = (1 - a) * grid[i1, j0] + a * grid[i1, j1]
    return (1 - b) * top + b * bot


def horizon_map(
    grid: Float[Array, "R R"],
    xy: Float[Array, "n 2"],
    n_azimuths: int = N_AZIMUTHS,
    n_steps: int = N_STEPS,
) -> Float[Array, "n K"]:
    """Horizon elevation (radians, ≥ 0) at ``xy`` toward azimuths ``2π k / K``.

    ``tan η(φ) = max_s (h(p + d_s u_φ) - h(p)) / d_s`` over ``d_s = reach · ((s + 1)/S)^1.5``
    (denser near the point, where the attached shadow is decided), clamped at 0.
    """
    phi = jnp.arange(n_azimuths, dtype=_F32) * (2 * jnp.pi / n_azimuths)
    u = jnp.stack([jnp.cos(phi), jnp.sin(phi)], -1)  # (K, 2)
    d = HORIZON_REACH * ((jnp.arange(n_steps, dtype=_F32) + 1) / n_steps) ** 1.5  # (S,)
    h0 = bilinear(grid, xy)  # (n,)

    def one_azimuth(uk):
        q = xy[:, None, :] + d[None, :, None] * uk  # (n, S, 2)
        tan = (bilinear(grid, q) - h0[:, None]) / d
        return jnp.arctan(jnp.maximum(jnp.max(tan, axis=1), 0.0))

    return jax.lax.map(one_azimuth, u).T  # (n, K)
