"""The default prior: trained on the package's own analytic materials, never on measured data.

No measured database ships with the package (the MERL data may not be redistributed), and
nothing is downloaded. The default prior is trained on :data:`DEFAULT_RECIPE`: ``n`` isotropic
materials drawn with a fixed seed from the analytic families of :mod:`abrdf_jax.materials`, each
a Lambertian base plus one specular lobe (GGX, Ward or Ashikhmin–Shirley; dielectric or metal;
roughness log-uniform) and, for some, a broader GGX haze lobe. It is built on first use (a few
seconds) and cached in the user cache folder (``<cache>/priors/``, see docs/cache.md) under a
key of the recipe and the package version; with the cache off it is built in memory each time.
"""

from __future__ import annotations

import hashlib
import json
import warnings

import numpy as np

from .._errors import InputError
from ._fused_settings import FUSED_DEFAULTS

#: What the default prior is trained on and with: ``K`` chosen by 6-fold cross-validation on these
#: draws themselves, ``λ`` on the MERL train split (exact iso102 samples; the draws' own
#: cross-validation prefers λ → 0, noise-free materials of their own family, and λ = 0.003 gave
#: MERL-train ΔE76 2.43 against 2.35 at 0.03), as the RBF's tuned defaults are: a number chosen
#: on the data, no data shipped (``python -m benchmarks.prior``, results/prior.md).
DEFAULT_RECIPE = {
    "seed": 20261202,
    "n": 300,
    "roughness": [0.03, 0.6],
    "families": {"ggx": 0.5, "ward": 0.25, "ashikhmin-shirley": 0.25},
    "metal_fraction": 0.3,
    "haze_fraction": 0.4,
    "lambert_only_fraction": 0.05,
    "k": 32,
    "lam": 0.03,
    "channels": "shared",
    "eps": 1e-6,
    # the basis at the sample positions: the training materials evaluated there (exact), not
    # the grid tables interpolated (abrdf_jax.prior.sample_basis; docs/prior.md)
    "basis": "models",
    # the fused model's hyper-parameters (``reconstruct --model fused``), chosen on MERL train
    "fused": {k: v for k, v in FUSED_DEFAULTS.items() if k != "chosen_on"},
}


#: The lobe families a recipe may draw, in the order of the draw.
FAMILIES = ("ggx", "ward", "ashikhmin-shirley")


def _draw(rng, recipe):
    """One material's parameters: a dict of lobes (plain floats / RGB lists)."""
    lo, hi = np.log(recipe["roughness"])
    lightness = rng.uniform(0.02, 0.8)
    albedo = np.clip(lightness * np.exp(rng.normal(0.0, 0.35, 3)), 0.0, 0.95)
    if rng.uniform() < recipe["lambert_only_fraction"]:
        return {"albedo": albedo, "lobes": []}
    # in a fixed order, not the dict's: a recipe read back from sorted JSON draws the same
    unknown = set(recipe["families"]) - set(FAMILIES)
    if unknown:
        raise InputError(f"recipe: unknown lobe families {sorted(unknown)}; known: {FAMILIES}")
    fam = [f for f in FAMILIES if f in recipe["families"]]
    family = fam[rng.choice(len(fam), p=[recipe["families"][f] for f in fam])]
    metal = rng.uniform() < recipe["metal_fraction"]
    if metal:
        albedo = albedo * 0.03
        f0 = np.clip(rng.uniform(0.35, 0.95) * np.exp(rng.normal(0.0, 0.25, 3)), 0.05, 0.98)
    else:
        f0 = np.full(3, rng.uniform(0.02, 0.08))
    alpha = float(np.exp(rng.uniform(lo, hi)))
    lobes = [(family, f0, alpha)]
    if rng.uniform() < recipe["haze_fraction"]:
        wide = float(np.exp(rng.uniform(np.log(alpha), np.log(0.8))))
        lobes.append(("ggx", f0 * rng.uniform(0.1, 0.5), wide))
    return {"albedo": albedo, "lobes": lobes}


def _lobe(family, f0, alpha):
    from ..materials._analytic import GGX, AshikhminShirley, Ward

    if family == "ggx":
        return GGX(diffuse=0.0, specular_f0=f0, alpha_x=alpha, alpha_y=alpha)
    if family == "ward":
        return Ward(diffuse=0.0, specular=f0, alpha_x=alpha, alpha_y=alpha)
    n = 2.0 / alpha**2 - 2.0  # the Phong exponent of a Beckmann roughness α
    return AshikhminShirley(diffuse=0.0, specular=f0, n_u=n, n_v=n)


def default_training_models(recipe: dict | None = None):
    """The default prior's training materials as analytic parts: ``(parts, names)``, material
    ``i`` the sum of the models in ``parts[i]`` (a Lambertian base and its lobes)."""
    from ..materials._analytic import Lambertian

    recipe = DEFAULT_RECIPE if recipe is None else recipe
    rng = np.random.default_rng(recipe["seed"])
    parts, names = [], []
    for i in range(recipe["n"]):
        d = _draw(rng, recipe)
        parts.append([Lambertian(albedo=d["albedo"]), *(_lobe(*lobe) for lobe in d["lobes"])])
        kinds = "+".join(f"{f}({a:.3f})" for f, _, a in d["lobes"]) or "lambert"
        names.append(f"analytic-{i:03d}:{kinds}")
    return parts, names


def default_training_tables(recipe: dict | None = None):
    """The default prior's training set: ``(tables (n, 81, 81, 3) float32, names)``."""
    from ..materials._registry import dense_table

    parts, names = default_training_models(recipe)
    tables = [sum(dense_table(p, np.float64) for p in ps).astype(np.float32) for ps in parts]
    return np.stack(tables), names


def recipe_key(recipe: dict) -> str:
    from .. import __version__
    from ._file import OPTIONAL, PRIOR_FORMAT

    # the optional members too: a new one (the ceiling) rebuilds a default prior cached without it
    doc = {"recipe": recipe, "version": __version__, "format": PRIOR_FORMAT, "members": OPTIONAL}
    text = json.dumps(doc)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def build_default_prior(recipe: dict | None = None):
    """Train the default prior from :func:`default_training_tables` (no cache)."""
    from ._model import train_prior

    recipe = DEFAULT_RECIPE if recipe is None else recipe
    tables, names = default_training_tables(recipe)
    provenance = (
        "abrdf_jax default prior: trained on the package's own analytic materials (Lambert + "
        "GGX/Ward/Ashikhmin-Shirley lobes, isotropic, fixed seed), no measured data; built "
        "locally from the recipe, same licence as the package"
    )
    return train_prior(
        tables,
        names,
        weights=recipe.get("basis") == "models",
        k=recipe["k"],
        lam=recipe["lam"],
        channels=recipe["channels"],
        eps=recipe["eps"],
        extra_meta={
            "provenance": provenance,
            "recipe": recipe,
            "key": recipe_key(recipe),
            **(
                {"fused": {**recipe["fused"], "chosen_on": FUSED_DEFAULTS["chosen_on"]}}
                if "fused" in recipe
                else {}
            ),
        },
    )


def default_prior_path(cache_dir=None):
    """Where :func:`default_prior` keeps the default prior: ``<cache>/priors/default-KEY.npz``
    (``None`` with the cache off). Numpy only: the command line finds the file without JAX."""
    from .._cache import PRIORS, cache_dir as where

    folder = where(cache_dir)
    return None if folder is None else folder / PRIORS / f"default-{recipe_key(DEFAULT_RECIPE)}.npz"


def default_prior(cache_dir=None):
    """The default prior, from the user cache or built (and cached) on first use.

    Args:
        cache_dir: the cache folder (default: :func:`abrdf_jax._cache.cache_dir`'s choice;
            ``"off"``: build in memory, write nothing).

    Returns:
        A :class:`~abrdf_jax.prior.Prior` (float32).
    """
    from ._file import load_prior, save_prior

    path = default_prior_path(cache_dir)
    if path is None:
        return build_default_prior()
    if path.exists():
        try:
            return load_prior(path)
        except InputError as e:  # a damaged cache entry is rebuilt, and said so
            warnings.warn(f"rebuilding the default prior: {e}", stacklevel=2)
    prior = build_default_prior()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_prior(prior, path)
    except (OSError, InputError) as e:
        warnings.warn(f"could not cache the default prior at {path}: {e}", stacklevel=2)
    return prior
