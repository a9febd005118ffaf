"""Figures (ABRDF images, lit spheres, reference/reconstruction comparisons) and the Mitsuba 3
BSDF of a table or BTF (``abrdf_bsdf``) with the scenes of ``abrdf-jax render`` (``render_table``,
``render_views``, ``scene_figure``; the ``render`` extra: ``pip install abrdf_jax[render]``)."""

from ._figures import abrdf_image as abrdf_image
from ._comparison import comparison_figure as comparison_figure
from ._mitsuba_bsdf import abrdf_bsdf as abrdf_bsdf
from ._mitsuba_bsdf import register_plugin as register_plugin
from ._figures import exposure_of as exposure_of
from ._figures import grid_weights as grid_weights
from ._figures import interpolate_table as interpolate_table
from ._figures import render_sphere as render_sphere
from ._scene import render_table as render_table
from ._scene_figure import render_views as render_views
from ._scene_figure import scene_figure as scene_figure
from ._scene_figure import view_error as view_error
from ._variants import llvm_library as llvm_library

__all__ = [
    "abrdf_bsdf",
    "abrdf_image",
    "comparison_figure",
    "exposure_of",
    "grid_weights",
    "interpolate_table",
    "llvm_library",
    "register_plugin",
    "render_sphere",
    "render_table",
    "render_views",
    "scene_figure",
    "view_error",
]
