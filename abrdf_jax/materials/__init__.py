"""Ground-truth materials: analytic models, a procedural non-reciprocal surface, the merl-nbrdf
neural fits of measured BRDFs, and a registry of named materials.

Every material is an ``eqx.Module`` called as ``material(wi, wv) -> (..., 3)``: the ABRDF
``f_r cos θi`` in linear RGB for illumination ``wi`` and view ``wv`` unit vectors (z = normal),
zero below the horizon; jit-, vmap- and grad-friendly, in the dtype of the inputs.
"""

from ._analytic import GGX as GGX
from ._analytic import AbstractMaterial as AbstractMaterial
from ._analytic import AshikhminShirley as AshikhminShirley
from ._analytic import Lambertian as Lambertian
from ._analytic import RoughStructured as RoughStructured
from ._analytic import Ward as Ward
from ._nbrdf import DATA_ENV as DATA_ENV
from ._nbrdf import DataNotFoundError as DataNotFoundError
from ._nbrdf import NeuralBRDF as NeuralBRDF
from ._nbrdf import default_data_dir as default_data_dir
from ._nbrdf import load_nbrdf as load_nbrdf
from ._nbrdf import load_nbrdf_all as load_nbrdf_all
from ._nbrdf import load_tables81 as load_tables81
from ._nbrdf import merl_split as merl_split
from ._nbrdf import nbrdf_input as nbrdf_input
from ._nbrdf import nbrdf_names as nbrdf_names
from ._nbrdf import stack_nbrdf as stack_nbrdf
from ._registry import default_materials as default_materials
from ._registry import dense_table as dense_table
from ._registry import get_material as get_material
from ._registry import is_anisotropic as is_anisotropic
from ._registry import material_info as material_info
from ._registry import material_names as material_names

__all__ = [
    "AbstractMaterial", "AshikhminShirley", "DATA_ENV", "DataNotFoundError", "GGX", "Lambertian",
    "NeuralBRDF", "RoughStructured", "Ward", "default_data_dir", "default_materials",
    "dense_table", "get_material", "is_anisotropic", "load_nbrdf", "load_nbrdf_all",
    "load_tables81", "material_info", "material_names", "merl_split", "nbrdf_input",
    "nbrdf_names", "stack_nbrdf",
]
