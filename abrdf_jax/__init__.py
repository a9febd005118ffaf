"""abrdf_jax: restore a material's full ABRDF from sparse slice measurements, in JAX.

The method is J. Filip, "Restoring Illumination and View Dependent Data from Sparse Samples",
ICPR 2012. Data flow, module by module (docs/notes.md has the map): measurements
(``_measurements``, ``io``) → slices (``_slices``) → toroidal subspaces (``_subspace``) → value
space (``_values``) → RBF in pair coordinates (``_coords``, ``_kernels``, ``_rbf``) → ABRDF table
(``_pipeline``, or one matrix: ``_operator``).

The names below are loaded on first use (PEP 562), so ``import abrdf_jax`` and the command line's
``--help`` do not import JAX; ``abrdf_jax.reconstruct`` and friends import it when first touched.
"""

from __future__ import annotations

from ._errors import InputError as InputError
from ._lazy import lazy_exports

__version__ = "0.1.0"

# public name -> private module that defines it (the one place the public API is listed)
_EXPORTS = {
    "_grid": (
        "half_diff",
        "onion",
        "onion_from_vector",
        "pair_grid",
        "to_vector",
        "from_vector",
        "ubo_grid",
        "vector_from_onion",
        "centre_vectors",
    ),
    "_kernels": ("KERNELS",),
    "_coords": ("PARAMETERIZATIONS", "pair_coordinates"),
    "_measurements": (
        "Samples",
        "Measurements",
        "stack_measurements",
    ),
    "_grouping": ("estimate_alpha", "group_slices", "infer_pairs"),
    "_protocol": ("PROTOCOL_ALPHA_DEG", "PROTOCOL_COUNTS", "PROTOCOL_PAIRS", "protocol_counts"),
    "_slices": ("slice_angles", "slice_directions"),
    "_sampling": ("sample", "sample_model", "sample_table"),
    "_capture": ("simulate_capture",),
    "_subspace": ("RULES", "subspace"),
    "_rbf": (
        "RBFInterpolant",
        "SolveInfo",
        "fit_rbf",
        "fit_rbf_info",
        "rbf_interpolate",
        "rbf_system",
    ),
    "_params": ("Config", "Params", "PRESETS", "preset"),
    "_arrays": ("check_finite",),
    "_finite": ("require_finite",),
    "_pipeline": ("infer_budget", "reconstruct", "reconstruct_batch", "solve_info"),
    "_operator": ("ReconstructionOperator", "compile_operator"),
    "_host_operator": ("compile_numpy_operator",),
    "_smoothing": ("slice_smoothing",),
    "_bivariate": ("bivariate_coordinates", "bivariate_matrix", "reconstruct_bivariate"),
}
_SUBPACKAGES = ("btf", "cli", "io", "materials", "metrics", "prior", "render", "select", "tuning")
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS, _SUBPACKAGES)
__all__ += ["InputError", "__version__"]
