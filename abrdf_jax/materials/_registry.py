"""Named ground-truth materials: the embedded synthetic set and the shared neural fits.

The default set needs no data: eight analytic/procedural materials with realistic parameters
(ABRDF mostly 0.01-1 on the UBO2003 grid, highlights up to a few tens). They supply what the
measured data cannot: anisotropy (``ward-*``, ``ashikhmin-satin``, ``ggx-aniso-metal``,
``rough-*``) and non-reciprocity (``rough-*``). Names ``"nbrdf:<name>"`` load a merl-nbrdf network
from the shared data folder (isotropic and reciprocal, fits of measurements).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._grid import pair_grid, to_vector
from ._catalogue import CATALOGUE, check_name, nbrdf_name
from ._analytic import GGX, AshikhminShirley, Lambertian, RoughStructured, Ward
from ._nbrdf import load_nbrdf

# name -> constructor (the catalogue, _catalogue.CATALOGUE, says what each is)
_MAKERS = {
    "lambert-clay": lambda: Lambertian(albedo=[0.55, 0.38, 0.28]),
    "ward-brushed-steel": lambda: Ward(
        diffuse=[0.04, 0.04, 0.045], specular=[0.30, 0.30, 0.32], alpha_x=0.05, alpha_y=0.25
    ),
    "ward-rotated-45": lambda: Ward(
        diffuse=[0.10, 0.05, 0.03],
        specular=[0.35, 0.22, 0.14],
        alpha_x=0.10,
        alpha_y=0.35,
        rotation=math.pi / 4,
    ),
    "ashikhmin-satin": lambda: AshikhminShirley(
        diffuse=[0.45, 0.10, 0.16], specular=[0.06, 0.05, 0.05], n_u=8.0, n_v=120.0
    ),
    "ggx-plastic": lambda: GGX(
        diffuse=[0.08, 0.25, 0.55], specular_f0=0.04, alpha_x=0.1, alpha_y=0.1
    ),
    "ggx-aniso-metal": lambda: GGX(
        diffuse=0.0,
        specular_f0=[0.95, 0.72, 0.33],
        alpha_x=0.07,
        alpha_y=0.30,
        rotation=math.pi / 6,
    ),
    "rough-fabric": lambda: RoughStructured(
        diffuse=[0.60, 0.22, 0.15],
        specular_f0=0.03,
        roughness=0.5,
        groove_slope=0.45,
        fill=[0.55, 0.35, 0.25],
        shadow_sharpness=2.5,
        mask_sharpness=16.0,
        forward=[0.30, 0.12, 0.09],
        forward_kappa=5.0,
        forward_lift=0.3,
    ),
    "rough-grooves": lambda: RoughStructured(
        diffuse=[0.22, 0.22, 0.20],
        specular_f0=[0.35, 0.33, 0.30],
        roughness=0.18,
        groove_slope=0.7,
        fill=0.1,
        shadow_sharpness=4.0,
        mask_sharpness=20.0,
        forward=0.05,
        forward_kappa=8.0,
        forward_lift=0.5,
        rotation=math.pi / 12,
    ),
}
if tuple(_MAKERS) != tuple(CATALOGUE):
    raise AssertionError("materials: _MAKERS and _catalogue.CATALOGUE list different names")


def default_materials() -> dict[str, eqx.Module]:
    """The embedded default materials, ``{name: material}`` (no data needed)."""
    return {name: make() for name, make in _MAKERS.items()}


def get_material(name: str, data_dir=None) -> eqx.Module:
    """A material by name: a default one, or ``"nbrdf:<merl-name>"`` from the shared data.

    Args:
        name: one of :func:`material_names`, or ``"nbrdf:"`` followed by a merl-nbrdf name
            (e.g. ``"nbrdf:gold-paint"``).
        data_dir: shared data folder for ``nbrdf:`` names (default ``default_data_dir()``).

    Returns:
        The material, an ``eqx.Module`` callable as ``material(wi, wv)``.

    Raises:
        InputError: on an unknown name (the message lists the valid ones); a ``DataNotFoundError``
            (an InputError) if an ``nbrdf:`` name is asked for and the data are missing.
    """
    check_name(name)
    sub = nbrdf_name(name)
    if sub is not None:
        return load_nbrdf(sub, data_dir)
    return _MAKERS[name]()


def dense_table(material, dtype=np.float32) -> np.ndarray:
    """A material evaluated on all 81 x 81 UBO2003 direction pairs.

    Args:
        material: a material module, or a name accepted by :func:`get_material`.
        dtype: numpy dtype of the result. The evaluation runs in float64 when ``dtype`` is
            float64 and JAX has x64 enabled, else in float32.

    Returns:
        ``table[i, v, c]``, shape ``(81, 81, 3)``: illumination direction ``i``, view direction
        ``v`` (UBO2003 order, ``abrdf_jax._grid.ubo_grid``), linear RGB ABRDF.

    Raises:
        InputError: on an unknown material name.
    """
    if isinstance(material, str):
        material = get_material(material)
    wide = np.dtype(dtype) == np.float64 and jax.config.read("jax_enable_x64")
    work = jnp.float64 if wide else jnp.float32
    ti, pi, tv, pv = (np.deg2rad(a) for a in pair_grid())
    wi = to_vector(jnp.asarray(ti, work), jnp.asarray(pi, work))
    wv = to_vector(jnp.asarray(tv, work), jnp.asarray(pv, work))
    out = np.asarray(material(wi, wv))  # compiled inside (AbstractMaterial.__call__)
    return out.reshape(81, 81, 3).astype(dtype)
