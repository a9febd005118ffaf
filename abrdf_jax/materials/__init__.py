"""Ground-truth materials: analytic models, a procedural non-reciprocal surface, the merl-nbrdf
neural fits of measured BRDFs, and a registry of named materials.

Every material is an ``eqx.Module`` called as ``material(wi, wv) -> (..., 3)``: the ABRDF
``f_r cos θi`` in linear RGB for illumination ``wi`` and view ``wv`` unit vectors (z = normal),
zero below the horizon; jit-, vmap- and grad-friendly, in the dtype of the inputs.
"""

from __future__ import annotations

from .._lazy import lazy_exports

# public name -> private module that defines it; loaded on first use, so listing the built-in
# materials (the catalogue) imports no JAX
_EXPORTS = {
    "_analytic": (
        "GGX",
        "AbstractMaterial",
        "AshikhminShirley",
        "Lambertian",
        "RoughStructured",
        "Ward",
    ),
    "_nbrdf": (
        "DATA_ENV",
        "DataNotFoundError",
        "NeuralBRDF",
        "default_data_dir",
        "load_nbrdf",
        "load_nbrdf_all",
        "load_tables81",
        "merl_split",
        "nbrdf_input",
        "nbrdf_names",
        "stack_nbrdf",
    ),
    "_catalogue": (
        "CATALOGUE",
        "NBRDF_PREFIX",
        "check_name",
        "is_anisotropic",
        "material_info",
        "material_names",
    ),
    "_registry": ("default_materials", "dense_table", "get_material"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS)
