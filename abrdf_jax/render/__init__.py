"""Figures (ABRDF images, lit spheres, reference/reconstruction comparisons) and the Mitsuba 3
BSDF of a table or BTF (``abrdf_bsdf``; the ``render`` extra: ``pip install abrdf_jax[render]``)."""

from ._figures import abrdf_image as abrdf_image
from ._comparison import comparison_figure as comparison_figure
from ._mitsuba_bsdf import abrdf_bsdf as abrdf_bsdf
from ._mitsuba_bsdf import register_plugin as register_plugin
from ._figures import exposure_of as exposure_of
from ._figures import grid_weights as grid_weights
from ._figures import interpolate_table as interpolate_table
from ._figures import render_sphere as render_sphere

__all__ = [
    "abrdf_bsdf",
    "abrdf_image",
    "comparison_figure",
    "exposure_of",
    "grid_weights",
    "interpolate_table",
    "register_plugin",
    "render_sphere",
]
