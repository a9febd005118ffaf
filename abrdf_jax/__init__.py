"""abrdf_jax: restore a material's full ABRDF from sparse slice measurements, in JAX.

The method is J. Filip, "Restoring Illumination and View Dependent Data from Sparse Samples",
ICPR 2012. Data flow, module by module: measurements (``_samples``, ``io``) → slices
(``_slices``) → toroidal subspaces (``_subspace``) → RBF in onion coordinates (``_grid``,
``_kernels``, ``_rbf``) → ABRDF table (``_pipeline``).
"""

from ._errors import InputError as InputError
from ._grid import (
    half_diff as half_diff,
    onion as onion,
    onion_from_vector as onion_from_vector,
    pair_grid as pair_grid,
    to_vector as to_vector,
    from_vector as from_vector,
    ubo_grid as ubo_grid,
    vector_from_onion as vector_from_onion,
)
from ._kernels import KERNELS as KERNELS
from ._operator import ReconstructionOperator as ReconstructionOperator, compile_operator as compile_operator
from ._params import Config as Config, Params as Params
from ._pipeline import (
    infer_budget as infer_budget,
    reconstruct as reconstruct,
    reconstruct_batch as reconstruct_batch,
    sample as sample,
)
from ._rbf import RBFInterpolant as RBFInterpolant, fit_rbf as fit_rbf, rbf_interpolate as rbf_interpolate
from ._samples import Samples as Samples
from ._slices import (
    Measurements as Measurements,
    estimate_alpha as estimate_alpha,
    group_slices as group_slices,
    stack_measurements as stack_measurements,
)
from ._subspace import RULES as RULES, subspace as subspace

from . import io as io, materials as materials, metrics as metrics, render as render, select as select, tuning as tuning

__version__ = "0.1.0"
