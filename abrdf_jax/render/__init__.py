"""Figures: ABRDF images, lit spheres and reference/reconstruction comparisons (public API)."""

from ._figures import abrdf_image as abrdf_image
from ._comparison import comparison_figure as comparison_figure
from ._figures import exposure_of as exposure_of
from ._figures import grid_weights as grid_weights
from ._figures import interpolate_table as interpolate_table
from ._figures import render_sphere as render_sphere

__all__ = [
    "abrdf_image",
    "comparison_figure",
    "exposure_of",
    "grid_weights",
    "interpolate_table",
    "render_sphere",
]
