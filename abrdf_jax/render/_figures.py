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
import io as _io
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..io._atomic import atomic_write
from ..io._tables import check_table
from ..metrics import expose, srgb_encode, tonemap
from .._grid import UBO_THETAS_DEG, ubo_grid

_LUMA = np.array([0.2126, 0.7152, 0.0722])
_BACKGROUND = 0.12  # display value (sRGB-encoded) of the area around a sphere
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
    index = source[verts]
    return index.reshape(*shape, 3), bary.reshape(*shape, 3), above.reshape(shape)


def interpolate_table(table, wi, wv) -> np.ndarray:
    """Look a table up at arbitrary (illumination, view) direction pairs.

    Each direction is interpolated barycentrically over a triangulation of the UBO grid (see
    :func:`grid_weights`); the pair's value is the product-weighted sum over the 3 × 3 grid
    pairs. At grid directions the table value is reproduced exactly (up to rounding).

    Args:
        table: ``(81, 81, 3)`` ABRDF.
        wi, wv: arrays ``(..., 3)`` of illumination and view vectors in the local frame.

    Returns:
        float64 array ``(..., 3)``; pairs with either direction at or below the horizon are 0.
    """
    t = _check_table(table)
    ii, wgt_i, up_i = grid_weights(wi)
    iv, wgt_v, up_v = grid_weights(wv)
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
    light: tuple[float, float] = (50.0, 135.0),
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
        table: ``(81, 81, 3)`` ABRDF.
        light: light direction ``(θ, φ)`` in degrees, world frame.
        view: camera direction ``(θ, φ)`` in degrees, world frame; ``(0, 0)`` looks straight
            down the ``z`` axis.
        size: image side in pixels.
        exposure: tone-mapping exposure; ``None`` uses :func:`exposure_of` of ``table``.
        supersample: samples per pixel side; display values are box-averaged (anti-aliasing).

    Returns:
        float32 array ``(size, size, 3)`` of display values in ``[0, 1]``; points lit from
        below their horizon (or seen below it) are black, the background is dark grey.

    Raises:
        InputError: wrong table shape, non-finite values, or ``size < 1``.
    """
    t = _check_table(table)
    size, ss = _check_positive_int("size", size), _check_positive_int("supersample", supersample)
    e = exposure_of(t) if exposure is None else float(exposure)
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

    radiance = interpolate_table(t, local(l_w), local(c))
    img = np.full((m, m, 3), _BACKGROUND, dtype=np.float32)
    img[inside] = _display(radiance, e)
    if ss > 1:
        img = img.reshape(size, ss, size, ss, 3).mean(axis=(1, 3))
    return img


# --------------------------------------------------------------------------------------------
# Comparison figure
# --------------------------------------------------------------------------------------------


def check_figure_path(path) -> Path:
    """Validate a figure output path (extension, existing folder) before any work is done.

    Raises:
        InputError: unknown extension or missing folder.
    """
    path = Path(path)
    if path.suffix.lower() not in _FIG_FORMATS:
        raise InputError(
            f"{path}: unknown figure format {path.suffix or '(none)'!r}; use one of {', '.join(_FIG_FORMATS)}"
        )
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{path}: folder {parent} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    return path


def _caption(metrics: dict | None) -> str:
    fields = (("de76", "ΔE76 {:.2f}"), ("rmse8", "RMSE8 {:.2f}"), ("psnr", "PSNR {:.1f} dB"))
    m = metrics or {}
    return " / ".join(f.format(float(m[k])) for k, f in fields if m.get(k) is not None)


def comparison_figure(
    rows, path, *, light=(50.0, 135.0), sphere_size: int = 160, dpi: int = 100
) -> Path:
    """Save a figure comparing references with reconstructions, one material per row.

    Each row shows the reference ABRDF image, the reconstructed one, and the two lit spheres,
    all tone-mapped with the reference's exposure, with ``ΔE76 / RMSE8 / PSNR`` as a caption.

    Args:
        rows: sequence of ``(name, ref_table, rec_table, metrics)``; ``metrics`` is a dict with
            keys ``"de76"``, ``"rmse8"``, ``"psnr"`` (as :func:`abrdf_jax.metrics.evaluate`
            returns) or ``None``.
        path: output file, ``.png`` (also ``.pdf``/``.svg``); written atomically.
        light: light direction ``(θ, φ)`` in degrees for the spheres.
        sphere_size: sphere image side in pixels.
        dpi: resolution of the saved figure.

    Returns:
        The path written.

    Raises:
        InputError: no rows, a malformed table, unknown extension or missing folder.
    """
    # A bare Figure (no pyplot) renders through Agg without touching any GUI backend.
    from matplotlib.figure import Figure

    path = check_figure_path(path)
    rows = list(rows)
    if not rows:
        raise InputError("comparison_figure: no rows to draw")

    n = len(rows)
    cell, caption_h, top, bottom = 1.9, 0.35, 0.35, 0.3  # inches
    height = n * (cell + caption_h) + top + bottom
    width = 4 * cell + 0.5
    fig = Figure(figsize=(width, height), dpi=dpi)
    axes = fig.subplots(n, 4, squeeze=False)
    margins = dict(left=0.5 / width, right=0.99, top=1 - top / height, bottom=bottom / height)
    fig.subplots_adjust(wspace=0.06, hspace=caption_h / cell, **margins)
    heads = ("ABRDF reference", "ABRDF reconstruction", "sphere reference", "sphere reconstruction")
    for r, row in enumerate(rows):
        if len(row) != 4:
            raise InputError(
                f"comparison_figure: row {r} has {len(row)} items, expected (name, ref, rec, metrics)"
            )
        name, ref, rec, metrics = row
        ref = _check_table(ref, f"{name}: reference")
        rec = _check_table(rec, f"{name}: reconstruction")
        e = exposure_of(ref)  # one exposure per material, set by the reference (PROTOCOL.md)
        images = (
            abrdf_image(ref, e),
            abrdf_image(rec, e),
            render_sphere(ref, light=light, size=sphere_size, exposure=e),
            render_sphere(rec, light=light, size=sphere_size, exposure=e),
        )
        for c, (ax, img) in enumerate(zip(axes[r], images)):
            ax.imshow(img, interpolation="nearest", vmin=0.0, vmax=1.0)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(heads[c], fontsize=8)
            if c == 0:
                ax.set_ylabel(str(name), fontsize=9)
        caption = _caption(metrics)
        if caption:
            box = axes[r][0].get_position()
            fig.text(0.5, box.y0 - 0.06 / height, caption, ha="center", va="top", fontsize=8.5)
    note = "ABRDF images: rows = illumination, columns = view (UBO order)"
    fig.text(0.5, 0.04 / height, note, ha="center", va="bottom", fontsize=7, color="0.35")
    buf = _io.BytesIO()
    fig.savefig(buf, format=path.suffix.lower().lstrip("."), dpi=dpi)
    with atomic_write(path, "wb") as f:
        f.write(buf.getvalue())
    return path
