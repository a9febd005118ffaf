"""The scene of ``abrdf-jax render``: an ABRDF table on a shape, under a light, in Mitsuba 3.

One camera for every shape: perspective, 30° field of view, 4 units from the origin, raised 20°
above the horizontal, so the top of a shape is seen as well as its side. Two shapes
(:data:`SHAPES`):

- ``sphere``: radius 1, its pole turned up (+y), so the tangent of Mitsuba's parameterization
  (``dp/du``, the table's φ = 0 direction) runs along the parallels: every normal is shown once;
- ``cylinder``: radius 0.6, axis up, 1.6 high, closed by a disc on top; its tangent runs around
  the circumference, as on a lathe-brushed rod. The normal is constant along the axis, so a
  highlight becomes a vertical stripe whose width and shape show the lobe across and along the
  tangent: an anisotropic material's stripe differs from an isotropic one's, and from the
  sphere's round highlight.

Two lights (:data:`LIGHTS`), both procedural (nothing is downloaded):

- ``env``: a latitude-longitude environment, a grey sky brightening towards the zenith over a
  dark ground, with a square "window" (radiance 3, 40° wide) upper left behind the camera:
  glossy materials reflect the window, diffuse ones the gradient;
- ``point``: a point light upper left near the camera (intensity 30).

The integrator is ``direct`` (direct illumination, emitter and BSDF sampling with MIS) with the
emitters hidden from the camera, so the background is black with alpha 0 and every rendered
pixel shows the material. Images are linear RGB plus the film's alpha (pixel coverage).
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from .._names import RENDER_SIZE_RANGE, RENDER_SPP_RANGE
from .._names import check_registry
from ..io._tables import check_table
from ._mitsuba_bsdf import abrdf_bsdf

#: Image side and samples per pixel that :func:`render_table` accepts.
SIZE_RANGE, SPP_RANGE = RENDER_SIZE_RANGE, RENDER_SPP_RANGE
CAMERA = {"fov_deg": 30.0, "distance": 4.0, "elevation_deg": 20.0}
#: The point light's position and intensity, the environment window's direction and radiance.
POINT_LIGHT = {"position": (-2.0, 3.0, 3.0), "intensity": 30.0}
WINDOW = {"direction": (-0.5, 0.6, 0.62), "half_width_deg": 20.0, "radiance": 3.0}
ENV_SIZE = (64, 128)  # latitude-longitude rows x columns


def _sphere(mi, bsdf) -> dict:
    turn = mi.ScalarTransform4f().rotate([1, 0, 0], -90)  # the pole (+z) to +y
    return {"sphere": {"type": "sphere", "to_world": turn, "bsdf": bsdf}}


def _cylinder(mi, bsdf) -> dict:
    r, h = 0.6, 0.8
    cap = mi.ScalarTransform4f().translate([0, h, 0]).rotate([1, 0, 0], -90).scale(r)
    return {
        "side": {"type": "cylinder", "p0": [0, -h, 0], "p1": [0, h, 0], "radius": r, "bsdf": bsdf},
        "cap": {"type": "disk", "to_world": cap, "bsdf": {"type": "ref", "id": "material"}},
    }


#: Shape name -> the scene entries of that shape with the material ``bsdf``.
SHAPES = {"sphere": _sphere, "cylinder": _cylinder}
check_registry("RENDER_SHAPES", SHAPES)


def environment_map(rows: int = ENV_SIZE[0], cols: int = ENV_SIZE[1]) -> np.ndarray:
    """The ``env`` light's radiance ``(rows, cols, 3)``, float32, in Mitsuba's ``envmap`` layout
    (row 0 the zenith +y; column ``u`` the azimuth with direction ``(sin θ sin 2πu, cos θ,
    −sin θ cos 2πu)``): sky ``0.1 + 0.5·y^0.5`` above the horizon, ground 0.03, and the window."""
    theta = (np.arange(rows) + 0.5) / rows * np.pi
    phi = (np.arange(cols) + 0.5) / cols * 2.0 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], axis=-1)
    y = d[..., 1]
    sky = np.where(y > 0, 0.1 + 0.5 * np.sqrt(np.maximum(y, 0.0)), 0.03)
    w = np.asarray(WINDOW["direction"], np.float64)
    w /= np.linalg.norm(w)
    # a square window: both angles from its centre within the half width
    right = np.cross([0.0, 1.0, 0.0], w)
    right /= np.linalg.norm(right)
    up = np.cross(w, right)
    front = d @ w
    half = np.tan(np.radians(WINDOW["half_width_deg"]))
    inside = (front > 0) & (np.abs(d @ right) < half * front) & (np.abs(d @ up) < half * front)
    radiance = np.where(inside, WINDOW["radiance"], sky)
    return np.repeat(radiance[..., None], 3, axis=-1).astype(np.float32)


def _env(mi) -> dict:
    return {"type": "envmap", "bitmap": mi.Bitmap(environment_map())}


def _point(mi) -> dict:
    return {
        "type": "point",
        "position": list(POINT_LIGHT["position"]),
        "intensity": {"type": "rgb", "value": POINT_LIGHT["intensity"]},
    }


#: Light name -> its emitter entry.
LIGHTS = {"env": _env, "point": _point}
check_registry("RENDER_LIGHTS", LIGHTS)


def _check_int(name: str, value, bounds: tuple[int, int]) -> int:
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not ok or not bounds[0] <= value <= bounds[1]:
        raise InputError(f"{name} must be an integer in [{bounds[0]}, {bounds[1]}], got {value!r}")
    return int(value)


def scene_dict(mi, table, shape: str, light: str, size: int) -> dict:
    """The Mitsuba scene dictionary (the current variant) of ``table`` on ``shape`` under ``light``."""
    from .._names import lookup

    make_shape = lookup(SHAPES, shape, "shape")
    make_light = lookup(LIGHTS, light, "light")
    el = np.radians(CAMERA["elevation_deg"])
    eye = CAMERA["distance"] * np.array([0.0, np.sin(el), np.cos(el)])
    look = mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=[0, 0, 0], up=[0, 1, 0])
    film = {
        "type": "hdrfilm",
        "width": size,
        "height": size,
        "pixel_format": "rgba",
        "rfilter": {"type": "box"},
    }
    return {
        "type": "scene",
        "integrator": {"type": "direct", "hide_emitters": True},
        "sensor": {
            "type": "perspective",
            "fov": CAMERA["fov_deg"],
            "to_world": look,
            "film": film,
            "sampler": {"type": "independent"},
        },
        "material": abrdf_bsdf(table),
        **make_shape(mi, {"type": "ref", "id": "material"}),
        "light": make_light(mi),
    }


def render_table(
    table,
    shape: str = "sphere",
    size: int = 64,
    spp: int = 16,
    light: str = "env",
    variant: str = "scalar_rgb",
    seed: int = 0,
    probe: bool = True,
) -> np.ndarray:
    """Render an ABRDF table on a shape under a light in Mitsuba 3 (the ``render`` extra).

    Args:
        table: ``(81, 81, 3)`` ABRDF, linear RGB, value = BRDF · cos θi (``PROTOCOL.md``).
        shape: ``"sphere"`` or ``"cylinder"`` (module docstring: why these two).
        size: image side in pixels, in :data:`SIZE_RANGE`.
        spp: samples per pixel, in :data:`SPP_RANGE`.
        light: ``"env"`` (procedural environment) or ``"point"``.
        variant: a Mitsuba variant of :data:`abrdf_jax._names.RENDER_VARIANTS` (set globally);
            one other than ``scalar_rgb`` is first tried in a child process (``probe``).
        seed: the sampler's seed: the same arguments give the same image.

    Returns:
        float32 ``(size, size, 4)``: linear RGB and alpha (coverage; 0 on the background).

    Raises:
        InputError: a bad table, shape, light, size, spp or variant; Mitsuba missing (names the
            ``abrdf_jax[render]`` extra).
    """
    from ._variants import use_variant

    arr = check_table(table, "table").astype(np.float64)
    size = _check_int("size", size, SIZE_RANGE)
    spp = _check_int("spp", spp, SPP_RANGE)
    mi = use_variant(variant, check=probe)
    scene = mi.load_dict(scene_dict(mi, arr, shape, light, size))
    img = np.array(mi.render(scene, spp=spp, seed=int(seed)), dtype=np.float32)
    if img.shape != (size, size, 4) or not np.all(np.isfinite(img)):
        raise RuntimeError(f"Mitsuba returned an image of shape {img.shape} with non-finite values")
    return img
