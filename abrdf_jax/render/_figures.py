"""Figures: ABRDF tables as images, lit spheres, and reference/reconstruction comparisons.

Everything here is numpy and matplotlib (the non-interactive Agg backend); nothing is traced
by JAX. Tables are ``table[i, v, c]`` of shape ``(81, 81, 3)`` on the UBO2003 grid, linear RGB,
value = BRDF · cos θi (``PROTOCOL.md``).

Tone mapping follows ``PROTOCOL.md``'s metric, so that what a figure shows is what the metrics
measure: exposure ``e = 0.18 / median(Y)`` of the reference (the mean if the median is 0),
Reinhard's ``y / (1 + y)`` with negative values counted as 0, then the sRGB transfer curve.
Pass the reference's exposure when drawing a reconstruction so that both share one scale.
"""

from __future__ import annotations

import functools

import numpy as np

from .._errors import InputError
from ..io._tables import check_table
from ..metrics import expose, srgb_encode, tonemap
from .._grid import UBO_THETAS_DEG, ubo_grid

_LUMA = np.array([0.2126, 0.7152, 0.0722])
_BACKGROUND = 0.45  # display value (sRGB-encoded) around a sphere: mid grey, so the unlit
# (black) part of the sphere stands out from it
#: The default light of the spheres: upper left, near the camera, so little of the disc is unlit.
DEFAULT_LIGHT = (35.0, 135.0)
_N = 81
_FIG_FORMATS = (".png", ".pdf", ".svg")


# --------------------------------------------------------------------------------------------
# Tone mapping
# --------------------------------------------------------------------------------------------


def _check_table(table, name: str = "table") -> np.ndarray:
    check_table(table, name)  # shape, dtype and finite values, as every table the package reads
    return np.asarray(table, dtype=np.float64)


def _check_positive_int(name: str, value) -> int:
    if int(value) != value or value < 1:
        raise InputError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def exposure_of(reference) -> float:
    """The protocol's exposure of a reference table (:func:`abrdf_jax.metrics.expose`) as a float."""
    return float(expose(np.asarray(reference)))


def _display(rgb, exposure: float) -> np.ndarray:
    """Linear RGB to display values in ``[0, 1]`` as the protocol's metric does (float32):
    ``srgb_encode(tonemap(max(e · rgb, 0)))`` of :mod:`abrdf_jax.metrics`."""
    y = np.maximum(np.asarray(rgb, dtype=np.float64) * float(exposure), 0.0)
    return np.asarray(srgb_encode(tonemap(y)), dtype=np.float32)


def abrdf_image(table, exposure: float | None = None, scale: int = 1) -> np.ndarray:
    """An ABRDF table as an image, like the paper's Fig. 2 and 4.

    Rows are the illumination index ``i``, columns the view index ``v`` (both in UBO order:
    the normal first, then the rings by elevation), so the top-left pixel is light and camera
    at the normal.

    Args:
        table: ``(81, 81, 3)`` linear RGB ABRDF.
        exposure: tone-mapping exposure; ``None`` uses :func:`exposure_of` of ``table`` itself.
            Pass the reference's exposure for a reconstruction so both share one scale.
        scale: integer nearest-neighbour upscaling factor (``>= 1``).

    Returns:
        float32 array ``(81·scale, 81·scale, 3)`` of display values in ``[0, 1]``.

    Raises:
        InputError: wrong table shape, non-finite values, or ``scale < 1``.
    """
    t = _check_table(table)
    scale = _check_positive_int("scale", scale)
    img = _display(t, exposure_of(t) if exposure is None else float(exposure))
    return np.repeat(np.repeat(img, scale, axis=0), scale, axis=1) if scale > 1 else img


# --------------------------------------------------------------------------------------------
# Interpolation of a table at arbitrary directions
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _triangulation():
    """Delaunay triangulation of the UBO grid in the azimuthal-equidistant plane.

    Each direction maps to ``θ · (cos φ, sin φ)`` (θ in degrees): the rings become concentric
    circles and the normal the origin. A virtual ring at θ = 90° repeats the values of the 75°
    ring (nearest-ring extrapolation to the horizon), so every direction above the horizon lies
    inside the triangulation. Returns the matplotlib triangulation, its point locator and, per
    triangulation vertex, the UBO index whose value it carries.
    """
    import matplotlib.tri as mtri

    theta, phi = ubo_grid()
    outer = np.nonzero(np.isclose(theta, UBO_THETAS_DEG[-1]))[0]
    th = np.concatenate([theta, np.full(outer.size, 90.0)])
    ph = np.concatenate([phi, phi[outer]])
    source = np.concatenate([np.arange(theta.size), outer])
    x = th * np.cos(np.radians(ph))
    y = th * np.sin(np.radians(ph))
    tri = mtri.Triangulation(x, y)
    # Clamp radius: the inscribed radius of the virtual 90° polygon.
    r_max = 90.0 * np.cos(np.pi / outer.size) - 1e-6
    return tri, tri.get_trifinder(), source, r_max


def grid_weights(w) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Barycentric weights of directions over the UBO grid.

    Args:
        w: array ``(..., 3)`` of direction vectors in the local frame (``z`` the normal); they
            are normalised here.

    Returns:
        ``(index, weight, above)``: ``index`` int array ``(..., 3)`` of UBO indices, ``weight``
        float array ``(..., 3)`` summing to 1 (exactly ``(1, 0, 0)`` up to rounding at a grid
        direction), and ``above`` bool ``(...,)``, false for directions at or below the horizon
        (their weights are those of the nearest direction above it and should not be used).
    """
    index, bary, above, _ = _weights(w)
    return index, bary, above


def _weights(w):
    """:func:`grid_weights` and, per weight, whether it falls on the virtual 90° ring."""
    tri, finder, source, r_max = _triangulation()
    w = np.asarray(w, dtype=np.float64)
    shape = w.shape[:-1]
    w = w.reshape(-1, 3)
    norm = np.linalg.norm(w, axis=-1)
    w = w / np.where(norm > 0, norm, 1.0)[:, None]
    above = w[:, 2] > 0.0
    theta = np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))
    rxy = np.hypot(w[:, 0], w[:, 1])
    r = np.minimum(theta, r_max)
    # At the normal rxy = 0: the direction of the (zero) offset is irrelevant.
    scale = np.divide(r, rxy, out=np.zeros_like(r), where=rxy > 1e-300)
    px, py = w[:, 0] * scale, w[:, 1] * scale
    t = finder(px, py)
    if np.any(t < 0):  # cannot happen for finite input; guard against a silent garbage lookup
        raise RuntimeError("direction outside the UBO triangulation")
    verts = tri.triangles[t]  # (P, 3)
    x0, x1, x2 = (tri.x[verts[:, k]] for k in range(3))
    y0, y1, y2 = (tri.y[verts[:, k]] for k in range(3))
    det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
    b0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / det
    b1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / det
    bary = np.stack([b0, b1, 1.0 - b0 - b1], axis=-1)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=-1, keepdims=True)
    index, virtual = source[verts], verts >= _N  # vertices past the 81 directions are virtual
    return (
        index.reshape(*shape, 3),
        bary.reshape(*shape, 3),
        above.reshape(shape),
        virtual.reshape(*shape, 3),
    )


def interpolate_table(table, wi, wv) -> np.ndarray:
    """Look a table up at arbitrary (illumination, view) direction pairs.

    Each direction is interpolated barycentrically over a triangulation of the UBO grid (see
    :func:`grid_weights`); the pair's value is the product-weighted sum over the 3 × 3 grid
    pairs. At grid directions the table value is reproduced exactly (up to rounding). Beyond
    the 75° ring the view direction takes the nearest ring's values, while the illumination
    direction falls linearly to 0 at the horizon (an ABRDF value contains ``cos θi``).

    Args:
        table: ``(81, 81, 3)`` ABRDF.
        wi, wv: arrays ``(..., 3)`` of illumination and view vectors in the local frame.

    Returns:
        float64 array ``(..., 3)``; pairs with either direction at or below the horizon are 0.
    """
    t = _check_table(table)
    ii, wgt_i, up_i, virtual = _weights(wi)
    # An ABRDF holds cos θi, so it vanishes as the light reaches the horizon: the light's
    # virtual 90° ring carries 0 (the view's repeats the 75° ring).
    wgt_i = np.where(virtual, 0.0, wgt_i)
    iv, wgt_v, up_v, _ = _weights(wv)
    ii, wgt_i, up_i = np.broadcast_arrays(ii, wgt_i, up_i[..., None])
    iv, wgt_v, up_v = np.broadcast_arrays(iv, wgt_v, up_v[..., None])
    vals = t[ii[..., :, None], iv[..., None, :]]  # (..., 3, 3, 3)
    w = wgt_i[..., :, None] * wgt_v[..., None, :]
    out = np.einsum("...ab,...abc->...c", w, vals)
    visible = up_i[..., 0] & up_v[..., 0]
    return np.where(visible[..., None], out, 0.0)


# --------------------------------------------------------------------------------------------
# Lit sphere
# --------------------------------------------------------------------------------------------


def _direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def render_sphere(
    table,
    light: tuple[float, float] = DEFAULT_LIGHT,
    view: tuple[float, float] = (0.0, 0.0),
    size: int = 128,
    exposure: float | None = None,
    supersample: int = 2,
) -> np.ndarray:
    """A sphere of the material under one distant light, seen by an orthographic camera.

    World frame: ``z`` points to the default camera; ``x`` is the image's right, ``y`` its up.
    At each visible point the local frame has the sphere normal as ``z`` and, as tangent, the
    world ``x`` axis projected onto the tangent plane (``y`` where that projection vanishes), so
    anisotropic materials are oriented consistently over the sphere. Light and view directions
    are expressed in that frame and the table is interpolated there (:func:`interpolate_table`).
    The radiance is the ABRDF value itself (it already includes ``cos θi``, unit irradiance).

    Args:
        table: ``(81, 81, 3)`` ABRDF, interpolated between the 81 directions; or a material
            (any callable ``material(wi, wv) -> (..., 3)`` such as :mod:`abrdf_jax.materials`'
            models), evaluated exactly at every pixel's directions (a reference without the
            table's 15° sampling).
        light: light direction ``(θ, φ)`` in degrees, world frame.
        view: camera direction ``(θ, φ)`` in degrees, world frame; ``(0, 0)`` looks straight
            down the ``z`` axis.
        size: image side in pixels.
        exposure: tone-mapping exposure; ``None`` uses :func:`exposure_of` of ``table`` (of
            the material's dense table when ``table`` is a material).
        supersample: samples per pixel side; display values are box-averaged (anti-aliasing).

    Returns:
        float32 array ``(size, size, 3)`` of display values in ``[0, 1]``; points lit from
        below their horizon (or seen below it) are black, the background is mid grey.

    Raises:
        InputError: wrong table shape, non-finite values, or ``size < 1``.
    """
    material = table if callable(table) else None
    t = None if material is not None else _check_table(table)
    size, ss = _check_positive_int("size", size), _check_positive_int("supersample", supersample)
    if exposure is None:
        from ..materials import dense_table

        exposure = exposure_of(t if material is None else dense_table(material))
    e = float(exposure)
    l_w = _direction(*light)
    c = _direction(*view)
    # Camera frame: c points to the camera; 'right' is world x made orthogonal to c.
    ref = np.array([1.0, 0.0, 0.0]) if abs(c[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = ref - (ref @ c) * c
    right /= np.linalg.norm(right)
    up = np.cross(c, right)

    m = size * ss
    s = (np.arange(m) + 0.5) / m * 2.0 - 1.0
    u, v = np.meshgrid(s, -s)  # row 0 is the top of the image
    rr = u * u + v * v
    inside = rr < 1.0
    uu, vv = u[inside], v[inside]
    h = np.sqrt(np.clip(1.0 - uu * uu - vv * vv, 0.0, None))
    n = uu[:, None] * right + vv[:, None] * up + h[:, None] * c  # (P, 3) unit normals

    ex = np.array([1.0, 0.0, 0.0])
    tan = ex - (n @ ex)[:, None] * n
    tn = np.linalg.norm(tan, axis=-1)
    alt = np.array([0.0, 1.0, 0.0])
    tan_alt = alt - (n @ alt)[:, None] * n
    tan = np.where((tn > 1e-6)[:, None], tan, tan_alt)
    tan /= np.linalg.norm(tan, axis=-1, keepdims=True)
    bit = np.cross(n, tan)

    def local(d):
        return np.stack([tan @ d, bit @ d, n @ d], axis=-1)

    if material is None:
        radiance = interpolate_table(t, local(l_w), local(c))
    else:
        radiance = _evaluate_material(material, local(l_w), local(c))
    img = np.full((m, m, 3), _BACKGROUND, dtype=np.float32)
    img[inside] = _display(radiance, e)
    if ss > 1:
        img = img.reshape(size, ss, size, ss, 3).mean(axis=(1, 3))
    return img


def _evaluate_material(material, wi, wv) -> np.ndarray:
    """A material's ABRDF at direction pairs ``(P, 3)``, as float64 numpy, 0 below the horizons.

    Raises:
        InputError: the material returns the wrong shape or non-finite values.
    """
    wi = np.broadcast_to(wi, np.broadcast_shapes(np.shape(wi), np.shape(wv)))
    wv = np.broadcast_to(wv, wi.shape)
    value = np.asarray(material(wi.astype(np.float32), wv.astype(np.float32)), dtype=np.float64)
    if value.shape != wi.shape:
        raise InputError(f"material returned shape {value.shape}, expected {wi.shape} (RGB last)")
    if not np.all(np.isfinite(value)):
        raise InputError("material returned non-finite values")
    above = (wi[:, 2] > 0) & (wv[:, 2] > 0)
    return np.where(above[:, None], value, 0.0)
