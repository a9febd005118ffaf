"""The reference/reconstruction comparison figure (``abrdf-jax demo``, notebooks).

One material per row: the reference and reconstructed ABRDF images with θ ticks, the ΔE76 of
every direction pair (the map whose mean is the protocol's ΔE76) with its colour bar, and the
two lit spheres; all tone-mapped with the reference's exposure (``PROTOCOL.md``), which the
row's caption states with the metrics.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._grid import UBO_COUNTS, UBO_THETAS_DEG
from ..io._atomic import write_figure
from ._figures import DEFAULT_LIGHT, _check_table, abrdf_image, exposure_of, render_sphere

_FIG_FORMATS = (".png", ".pdf", ".svg")
#: The ΔE76 colour scale's top (the same for every row, so rows compare).
DE_MAX = 20.0
_TONE = (
    "tone curve: exposure e = 0.18 / median luminance of the reference (per row), "
    "Reinhard y/(1+y), sRGB (PROTOCOL.md)"
)


def check_figure_path(path) -> Path:
    """Validate a figure output path (extension, existing folder) before any work is done.

    Raises:
        InputError: unknown extension, missing or read-only folder.
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
    if not os.access(parent, os.W_OK | os.X_OK):  # EROFS stops root too; permissions do not
        raise InputError(f"{path}: folder {parent} is not writable")
    return path


def _caption(metrics: dict | None, exposure: float) -> str:
    fields = (("de76", "ΔE76 {:.2f}"), ("rmse8", "RMSE8 {:.2f}"), ("psnr", "PSNR {:.1f} dB"))
    m = metrics or {}
    parts = [f.format(float(m[k])) for k, f in fields if m.get(k) is not None]
    return " / ".join(parts + [f"exposure e = {exposure:.3g}"])


def _ring_ticks(ax, ylabel: str | None) -> None:
    """θ ticks on an ABRDF image: ring boundaries as ticks, each ring's θ at its middle."""
    starts = np.concatenate([[0], np.cumsum(UBO_COUNTS)])  # 0, 1, 7, 19, 37, 57, 81
    middles = (starts[:-1] + starts[1:]) / 2 - 0.5
    labels = [f"{t:g}" for t in UBO_THETAS_DEG]
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_ticks(starts[1:-1] - 0.5, minor=True)
        axis.set_ticks(middles[2:], labels[2:])  # the normal and the 15° ring are too narrow
        axis.set_tick_params(which="major", length=0, labelsize=5.5, pad=1.5)
        axis.set_tick_params(which="minor", length=2.5)
    ax.set_xlabel("view θv (°)", fontsize=6.5, labelpad=1)
    if ylabel is None:
        ax.yaxis.set_tick_params(which="major", labelleft=False)
    else:
        ax.set_ylabel(ylabel, fontsize=7.5, labelpad=1)


def _unpack(r: int, row):
    if len(row) not in (4, 5):
        raise InputError(
            f"comparison_figure: row {r} has {len(row)} items, expected "
            "(name, ref, rec, metrics) or (name, ref, rec, metrics, material)"
        )
    name, ref, rec, metrics = row[:4]
    material = row[4] if len(row) == 5 else None
    if material is not None and not callable(material):
        raise InputError(f"comparison_figure: row {r}'s material is not callable as m(wi, wv)")
    ref = _check_table(ref, f"{name}: reference")
    rec = _check_table(rec, f"{name}: reconstruction")
    if ref.shape != rec.shape:
        raise InputError(f"{name}: reference {ref.shape} and reconstruction {rec.shape} differ")
    return str(name), ref, rec, metrics, material


def comparison_figure(
    rows, path, *, light=DEFAULT_LIGHT, sphere_size: int = 160, dpi: int = 100
) -> Path:
    """Save a figure comparing references with reconstructions, one material per row.

    Columns: the reference ABRDF image, the reconstructed one, the ΔE76 of every direction pair
    (:func:`abrdf_jax.metrics.delta_e76_pairs`, colour bar 0 to :data:`DE_MAX`), the reference
    sphere and the reconstructed one (:func:`~abrdf_jax.render.render_sphere`). All share the
    reference's exposure; the caption gives ``ΔE76 / RMSE8 / PSNR`` and the exposure, the
    footer the tone curve and the light.

    Args:
        rows: sequence of ``(name, ref_table, rec_table, metrics)`` or ``(name, ref_table,
            rec_table, metrics, material)``. ``metrics`` is a dict with keys ``"de76"``,
            ``"rmse8"``, ``"psnr"`` (as :func:`abrdf_jax.metrics.evaluate` returns) or
            ``None``; ``material`` (a callable ``material(wi, wv)``, optional) draws the
            reference sphere exactly instead of from the interpolated 81×81 table.
        path: output file, ``.png`` (also ``.pdf``/``.svg``); written atomically.
        light: light direction ``(θ, φ)`` in degrees for the spheres.
        sphere_size: sphere image side in pixels.
        dpi: resolution of the saved figure.

    Returns:
        The path written.

    Raises:
        InputError: no rows, a malformed row or table, unknown extension or missing folder.
    """
    # A bare Figure (no pyplot) renders through Agg without touching any GUI backend.
    from matplotlib.figure import Figure

    from ..metrics import delta_e76_pairs

    path = check_figure_path(path)
    rows = [_unpack(r, row) for r, row in enumerate(rows)]
    if not rows:
        raise InputError("comparison_figure: no rows to draw")

    n = len(rows)
    cell, below, top, bottom, left = 1.9, 0.55, 0.3, 0.85, 0.62  # inches
    height = n * (cell + below) + top + bottom
    ratios = [1, 1, 1, 0.07, 0.25, 1, 1]  # images, colour bar, a gap, spheres
    width = left + cell * sum(ratios) + 0.2
    fig = Figure(figsize=(width, height), dpi=dpi)
    grid = fig.add_gridspec(
        n,
        len(ratios),
        width_ratios=ratios,
        left=left / width,
        right=1 - 0.2 / width,
        top=1 - top / height,
        bottom=bottom / height,
        wspace=0.08,
        hspace=below / cell,
    )
    exact = any(row[4] is not None for row in rows)
    heads = {
        0: "ABRDF reference",
        1: "ABRDF reconstruction",
        2: "ΔE76 per direction pair",
        5: "sphere reference" + (" (model, exact)" if exact else ""),
        6: "sphere reconstruction",
    }
    for r, (name, ref, rec, metrics, material) in enumerate(rows):
        e = exposure_of(ref)  # one exposure per material, set by the reference (PROTOCOL.md)
        de = np.asarray(delta_e76_pairs(rec, ref))
        sphere_ref = ref if material is None else material
        tables = (abrdf_image(ref, e), abrdf_image(rec, e))
        spheres = (
            render_sphere(sphere_ref, light=light, size=sphere_size, exposure=e),
            render_sphere(rec, light=light, size=sphere_size, exposure=e),
        )
        axes = {c: fig.add_subplot(grid[r, c]) for c in heads}
        for c, img in zip((0, 1), tables):
            axes[c].imshow(img, interpolation="nearest", vmin=0.0, vmax=1.0, aspect="auto")
            _ring_ticks(axes[c], f"{name}\nlight θi (°)" if c == 0 else None)
        im = axes[2].imshow(
            de, interpolation="nearest", cmap="magma", vmin=0.0, vmax=DE_MAX, aspect="auto"
        )
        _ring_ticks(axes[2], None)
        bar = fig.colorbar(im, cax=fig.add_subplot(grid[r, 3]))
        bar.ax.tick_params(labelsize=6, length=2)
        for c, img in zip((5, 6), spheres):
            axes[c].imshow(img, interpolation="nearest", vmin=0.0, vmax=1.0)
            axes[c].set_xticks([])
            axes[c].set_yticks([])
        if r == 0:
            for c, title in heads.items():
                axes[c].set_title(title, fontsize=8)
        box = grid[r, 0:7].get_position(fig)
        fig.text(
            0.5, box.y0 - 0.3 / height, _caption(metrics, e), ha="center", va="top", fontsize=8
        )
    note = (
        "ABRDF images: rows = illumination, columns = view, UBO order (rings by θ; φ from 0 to "
        "360° within a ring).\n"
        f"Spheres: one distant light at θ = {light[0]:g}°, φ = {light[1]:g}°, orthographic camera "
        "at the normal; tables interpolated barycentrically between the 81 directions.\n" + _TONE
    )
    fig.text(0.5, 0.03 / height, note, ha="center", va="bottom", fontsize=6.5, color="0.3")
    return write_figure(fig, path, dpi=dpi)
