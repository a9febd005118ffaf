"""Mitsuba renders of a table beside its reference, their ΔE76 maps, and the figure of them
(``abrdf-jax render``, ``python -m benchmarks.render``).

Each view is one shape under one light (:mod:`abrdf_jax.render._scene`), rendered once for the
table and, given a reference, once for the reference with the same sampler seed, so both images
share their Monte Carlo noise and the map shows the materials' difference. Tone mapping is the
protocol's (``PROTOCOL.md``, as in the ABRDF figures): exposure ``e = 0.18 / median luminance``
of the reference's rendered pixels on the object (alpha > 0; the table's own without a
reference), Reinhard ``y / (1 + y)``, sRGB; the ΔE76 of every object pixel is
:func:`abrdf_jax.metrics.delta_e76_pairs` of the two images' linear pixels (its exposure is
the same ``e``). The background is mid grey in the figure and 0 in the map.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .._errors import InputError
from .._names import RENDER_SHAPES
from ..io._atomic import write_figure
from ._comparison import DE_MAX, check_figure_path
from ._figures import _BACKGROUND, _display, exposure_of
from ._scene import render_table

TONE = (
    "tone curve: exposure e = 0.18 / median luminance of the {whose} object pixels (per "
    "view, stated above each), Reinhard y/(1+y), sRGB (PROTOCOL.md); background grey"
)


class View(NamedTuple):
    """One shape under one light: the table's image and the reference's (``None`` without one),
    each ``(H, W, 4)`` linear RGB + alpha as :func:`~abrdf_jax.render.render_table` returns."""

    shape: str
    light: str
    rec: np.ndarray
    ref: np.ndarray | None


def render_views(
    table,
    reference=None,
    *,
    shapes=RENDER_SHAPES,
    lights=("env",),
    size: int = 64,
    spp: int = 16,
    variant: str = "scalar_rgb",
    seed: int = 0,
    on_image=None,
) -> list[View]:
    """Render ``table`` (and ``reference``) on every shape under every light.

    Args:
        table, reference: ``(81, 81, 3)`` ABRDF tables; ``reference`` optional.
        shapes, lights: names from :data:`abrdf_jax.render._scene.SHAPES` / ``LIGHTS``.
        size, spp, variant, seed: as :func:`~abrdf_jax.render.render_table`.
        on_image: called as ``on_image(shape, light, which, seconds)`` after each image
            (``which``: ``"reference"``, ``"reconstruction"``, or ``"table"`` without a
            reference), for progress lines.

    Returns:
        One :class:`View` per (shape, light), shapes outer.
    """
    views = []
    for shape in shapes:
        for light in lights:
            images = {}
            mine = "table" if reference is None else "reconstruction"
            for which, t in (("reference", reference), (mine, table)):
                if t is None:
                    continue
                t0 = time.perf_counter()
                kw = dict(shape=shape, light=light, size=size, spp=spp, variant=variant)
                images[which] = render_table(t, **kw, seed=seed)
                if on_image is not None:
                    on_image(shape, light, which, time.perf_counter() - t0)
            views.append(View(shape, light, images[mine], images.get("reference")))
    return views


def view_error(view: View) -> dict:
    """The view's exposure and ΔE76: ``{"exposure", "de76_map" (H, W), "de76_mean",
    "de76_p95", "de76_max"}`` over the object pixels (the ΔE entries ``None`` without a
    reference)."""
    from ..metrics import delta_e76_pairs

    base = view.rec if view.ref is None else view.ref
    mask = (base[..., 3] > 0) | (view.rec[..., 3] > 0)
    if not mask.any():
        raise InputError(f"{view.shape}/{view.light}: the shape covers no pixel")
    e = exposure_of(base[..., :3][mask])
    out = {"exposure": e, "de76_map": None, "de76_mean": None, "de76_p95": None, "de76_max": None}
    if view.ref is not None:
        de = np.zeros(mask.shape)
        de[mask] = np.asarray(delta_e76_pairs(view.rec[..., :3][mask], view.ref[..., :3][mask]))
        on = de[mask]
        out.update(
            de76_map=de,
            de76_mean=float(on.mean()),
            de76_p95=float(np.percentile(on, 95)),
            de76_max=float(on.max()),
        )
    return out


def display_image(rgba, exposure: float) -> np.ndarray:
    """An RGBA render as display values ``(H, W, 3)`` in ``[0, 1]``: the pixel's colour
    (un-premultiplied by its coverage) tone-mapped with ``exposure``, over the grey background."""
    rgba = np.asarray(rgba, np.float64)
    a = np.clip(rgba[..., 3:], 0.0, 1.0)
    colour = _display(rgba[..., :3] / np.maximum(a, 1e-6), exposure)
    return np.where(a > 0, a * colour + (1 - a) * _BACKGROUND, _BACKGROUND)


def scene_figure(rows, path, *, note: str = "", dpi: int = 100) -> Path:
    """Save the figure of rendered views, one row per ``(label, views)`` in ``rows``.

    Each view takes three columns with a reference (reference, reconstruction, ΔE76 map on a
    0–:data:`~abrdf_jax.render._comparison.DE_MAX` scale, one colour bar per row) or one
    without; its title names the light and the exposure, its caption the mean ΔE76. The
    footer gives the tone curve and ``note`` (the scene, size, spp, variant).

    Returns:
        The path written (``.png``, ``.pdf`` or ``.svg``, atomically).
    """
    from matplotlib.figure import Figure

    path = check_figure_path(path)
    rows = [(str(label), list(views)) for label, views in rows]
    if not rows or not all(views for _, views in rows):
        raise InputError("scene_figure: no views to draw")
    with_ref = rows[0][1][0].ref is not None
    per = 3 if with_ref else 1
    n_cols = max(len(v) for _, v in rows) * per
    ratios = [1.0] * n_cols + ([0.06] if with_ref else [])
    cell, left, top, bottom = 1.7, 0.5, 0.25, 0.75
    width = max(left + cell * sum(ratios) + 0.45, 4.5)  # room for the footer
    height = len(rows) * (cell + 0.45) + top + bottom
    fig = Figure(figsize=(width, height), dpi=dpi)
    grid = fig.add_gridspec(
        len(rows),
        len(ratios),
        width_ratios=ratios,
        left=left / width,
        right=1 - 0.45 / width,
        top=1 - top / height,
        bottom=bottom / height,
        wspace=0.06,
        hspace=0.45 / cell,
    )
    im = None
    for r, (label, views) in enumerate(rows):
        for k, view in enumerate(views):
            err = view_error(view)
            e = err["exposure"]
            panels = [("reconstruction" if with_ref else "table", display_image(view.rec, e))]
            if with_ref:
                panels = [("reference", display_image(view.ref, e)), *panels]
            for j, (title, img) in enumerate(panels):
                ax = fig.add_subplot(grid[r, k * per + j])
                ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
                ax.set_title(f"{title}, {view.light} (e = {e:.3g})", fontsize=6.5, pad=2)
                ax.set_xticks([])
                ax.set_yticks([])
                if k == 0 and j == 0:
                    ax.set_ylabel(f"{label}\n{view.shape}", fontsize=7.5)
            if with_ref:
                ax = fig.add_subplot(grid[r, k * per + 2])
                im = ax.imshow(err["de76_map"], cmap="magma", vmin=0, vmax=DE_MAX)
                ax.set_title(f"ΔE76, {view.light}", fontsize=6.5, pad=2)
                ax.set_xlabel(
                    f"mean {err['de76_mean']:.2f}, max {err['de76_max']:.1f}", fontsize=6.5
                )
                ax.set_xticks([])
                ax.set_yticks([])
        if with_ref:
            bar = fig.colorbar(im, cax=fig.add_subplot(grid[r, -1]))
            bar.ax.tick_params(labelsize=6, length=2)
    footer = TONE.format(whose="reference's" if with_ref else "table's own")
    footer += "\n" + note if note else ""
    fig.text(
        0.5, 0.05 / height, footer, ha="center", va="bottom", fontsize=6.5, color="0.3", wrap=True
    )
    return write_figure(fig, path, dpi=dpi)
