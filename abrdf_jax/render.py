"""Figures: ABRDF images, lit spheres and reference/reconstruction comparisons (public API)."""

from ._render import abrdf_image as abrdf_image
from ._render import comparison_figure as comparison_figure
from ._render import exposure_of as exposure_of
from ._render import grid_weights as grid_weights
from ._render import interpolate_table as interpolate_table
from ._render import render_sphere as render_sphere
from ._render import tonemap as tonemap

__all__ = [
    "abrdf_image",
    "comparison_figure",
    "exposure_of",
    "grid_weights",
    "interpolate_table",
    "render_sphere",
    "tonemap",
]
