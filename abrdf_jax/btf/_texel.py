"""The ABRDF of one texel of the procedural BTF: a tilted, shadowed, masked material mixture.

A texel sees a small piece of the height field (:mod:`._surface`). Its apparent BRDF, as a BTF
pixel records it (value = radiance under unit irradiance from ``wi``, rectified to the mean
plane, PROTOCOL.md's ``BRDF · cos θi`` for a flat texel), is modelled as

``ABRDF(wi, wv) = V_v(wv) · L_self + (1 - V_v(wv)) · L_occ``,

``L_self = f_mix(R wi, R wv) (n·wi) V_l(wi) + fill · ρ/π (n·wi)⁺ (1 - V_l(wi))``,

``L_occ = ρ/π (n_occ·wi)⁺ (fill + (1 - fill) V_l(wi))``,

- ``R`` takes the global frame to the texel's tilted frame (normal ``n`` from the height field,
  tangent the projection of ``x``); ``f_mix`` is a per-texel mixture of a Lambertian, an
  anisotropic Ward (brushed metal) and an anisotropic GGX (lacquer) lobe from
  :mod:`abrdf_jax.materials`, with per-texel albedo, roughness, anisotropy ratio and angle;
- ``V_l``, ``V_v`` are the light's and the view's visibility from the texel's horizon map, a
  smoothstep of (direction elevation − horizon elevation at its azimuth) of width
  :data:`SHADOW_SOFTNESS_DEG` on the light side (penumbrae of an extended source and of
  subsurface light) and :data:`MASK_SOFTNESS_DEG` on the view side (a camera sees crisp edges);
- ``fill`` lights cast shadows a little (interreflection and subsurface transport, light side
  only); ``ρ`` is the texel's diffuse albedo;
- a masked view ray ends on the occluder, a diffuse facet of slope equal to the horizon at the
  view azimuth, facing the camera.

Shadowing and masking act differently, the fill and the occluder depend on the light alone, and
the tilt makes ``n·wi`` differ from ``cos θi``: the texels are anisotropic and non-reciprocal, as
measured BTF texels are (Filip & Haindl, "Bidirectional texture function modeling: a state of the
art survey", IEEE TPAMI 31(11), 2009). Synthetic: a plausible test case, not a fit of any
measured material.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..materials import GGX, Lambertian, Ward

SHADOW_SOFTNESS_DEG = 6.0
MASK_SOFTNESS_DEG = 1.5
#: Diffuse part of the brushed-metal (Ward) class, as a fraction of the texel albedo.
METAL_DIFFUSE = 0.15
#: Fresnel reflectance of the lacquer (GGX) class at normal incidence.
LACQUER_F0 = 0.04


def _smoothstep(x):
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def horizon_at(horizon: Float[Array, " K"], phi: Float[Array, "..."]) -> Float[Array, "..."]:
    """Horizon elevation toward azimuth ``phi`` (radians), periodic linear interpolation."""
    k = horizon.shape[-1]
    x = jnp.mod(phi, 2 * jnp.pi) * (k / (2 * jnp.pi))
    k0 = jnp.floor(x)
    w = x - k0
    k0 = k0.astype(jnp.int32) % k
    return (1 - w) * horizon[k0] + w * horizon[(k0 + 1) % k]


def visibility(
    horizon: Float[Array, " K"], w: Float[Array, "... 3"], softness_rad
) -> Float[Array, "..."]:
    """Soft visibility of direction ``w`` over the horizon (1 well above it, 0 well below)."""
    elev = jnp.arcsin(jnp.clip(w[..., 2], -1.0, 1.0))
    eta = horizon_at(horizon, jnp.arctan2(w[..., 1], w[..., 0]))
    return _smoothstep((elev - eta) / softness_rad + 0.5)


class TexelModel(eqx.Module):
    """One texel's ABRDF (a material: ``texel(wi, wv) -> (..., 3)``); vmap it over texels.

    Attributes:
        normal: ``(3,)`` unit normal of the height field at the texel.
        weights: ``(3,)`` mixture weights of the Lambertian, Ward and GGX classes (sum 1).
        albedo: ``(3,)`` diffuse albedo (RGB).
        metal: ``(3,)`` specular reflectance of the Ward (brushed metal) class.
        roughness: RMS slope / GGX α of the glossy lobes (geometric mean of the two axes).
        aniso: ratio ``α_y / α_x`` of the glossy lobes (≥ 1).
        angle: direction of the lobes' ``x`` axis in the tangent plane, radians.
        fill: fraction of light reaching cast shadows.
        horizon: ``(K,)`` horizon elevations (radians) at azimuths ``2π k / K``.
    """

    normal: Float[Array, " 3"]
    weights: Float[Array, " 3"]
    albedo: Float[Array, " 3"]
    metal: Float[Array, " 3"]
    roughness: Float[Array, ""]
    aniso: Float[Array, ""]
    angle: Float[Array, ""]
    fill: Float[Array, ""]
    horizon: Float[Array, " K"]

    def frame(self, dtype) -> Float[Array, "3 3"]:
        """Rows: tangent, bitangent, normal of the tilted texel frame."""
        n = self.normal.astype(dtype)
        t = jnp.asarray([1.0, 0.0, 0.0], dtype) - n[0] * n
        t = t / jnp.linalg.norm(t)
        return jnp.stack([t, jnp.cross(n, t), n])

    def diffuse_albedo(self) -> Float[Array, " 3"]:
        w = self.weights
        return (w[0] + METAL_DIFFUSE * w[1] + w[2]) * self.albedo

    def __call__(
        self, wi: Float[Array, "... 3"], wv: Float[Array, "... 3"]
    ) -> Float[Array, "... 3"]:
        """ABRDF at illumination ``wi`` and view ``wv`` (global unit vectors, z = mean normal)."""
        dt = jnp.result_type(wi, wv)
        rot = self.frame(dt)
        wi_l, wv_l = wi @ rot.T, wv @ rot.T
        ax = self.roughness / jnp.sqrt(self.aniso)
        ay = self.roughness * jnp.sqrt(self.aniso)
        w = self.weights.astype(dt)
        rho = self.diffuse_albedo().astype(dt)
        # The glossy lobes are colourless (scalar parameters): evaluate them once, not per
        # channel, and colour them afterwards; every diffuse part is one Lambertian term.
        lobe = dict(alpha_x=ax, alpha_y=ay, rotation=self.angle)
        ward = Ward(diffuse=0.0, specular=1.0, **lobe)(wi_l, wv_l)
        ggx = GGX(diffuse=0.0, specular_f0=LACQUER_F0, **lobe)(wi_l, wv_l)
        lam = Lambertian(albedo=rho)(wi_l, wv_l)
        # f_mix (n·wi)
        base = lam + w[1] * self.metal.astype(dt) * ward[..., :1] + w[2] * ggx[..., :1]
        rho = rho / jnp.pi
        v_l = visibility(self.horizon, wi, np.deg2rad(SHADOW_SOFTNESS_DEG))[..., None]
        v_v = visibility(self.horizon, wv, np.deg2rad(MASK_SOFTNESS_DEG))[..., None]
        fill = self.fill.astype(dt)
        cos_n = jnp.maximum(wi_l[..., 2:3], 0.0)
        l_self = base * v_l + fill * rho * cos_n * (1 - v_l)
        phi_v = jnp.arctan2(wv[..., 1], wv[..., 0])
        eta = horizon_at(self.horizon, phi_v)
        sin_eta = jnp.sin(eta)
        n_occ = jnp.stack([sin_eta * jnp.cos(phi_v), sin_eta * jnp.sin(phi_v), jnp.cos(eta)], -1)
        cos_occ = jnp.maximum(jnp.sum(n_occ * wi, axis=-1, keepdims=True), 0.0)
        l_occ = rho * cos_occ * (fill + (1 - fill) * v_l)
        out = v_v * l_self + (1 - v_v) * l_occ
        above = ((wi[..., 2] > 0) & (wv[..., 2] > 0))[..., None]
        return jnp.where(above, out, 0.0)
