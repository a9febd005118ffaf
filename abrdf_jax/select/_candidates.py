"""The named models of the automatic choice, in complexity order (no JAX).

The ranks and their reasons are the module docstring of :mod:`abrdf_jax.select._select`; the
command line reads a fixed ``--model``'s settings here without importing the numerics.
"""

from __future__ import annotations

import dataclasses

from .._config import RECOMMENDED, Config
from .._errors import InputError
from .._names import MODEL_TOL


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A named model: its configuration (budget ``iso102``/``aniso204`` and settings) and rank."""

    name: str
    settings: dict
    rank: int
    description: str

    def config(self, **overrides) -> Config:
        """The :class:`Config` of this candidate (``overrides``: e.g. ``pairs``)."""
        return Config(**{**self.settings, **overrides})


def _rec(budget, **kw):
    return dict(budget=budget, **{**RECOMMENDED, **kw})


# name -> settings, in complexity order (see the module docstring)
_SETTINGS = {
    "iso": _rec("iso102"),
    "iso-linear": _rec("iso102", value_space="linear"),
    "iso-gaussian": _rec("iso102", kernel="gaussian", degree=0),
    "paper": dict(budget="iso102"),
    "aniso-average": _rec("aniso204", rule="average"),
    "aniso-crossing": _rec("aniso204", rule="crossing"),
    # The multiplicative rule on the samples, log after: in the log of the samples (the
    # recommended value space) it would multiply logs; there "crossing" is its counterpart.
    "aniso-log": _rec("aniso204", rule="log", value_space="log"),
    "aniso": _rec("aniso204"),
    "paper-aniso": dict(budget="aniso204"),
}
_DESCRIPTIONS = {
    "iso": "diagonal slices only (eq. 5); thin-plate spline on the log of the samples (recommended)",
    "iso-linear": "diagonal slices only; thin-plate spline on linear values",
    "iso-gaussian": "diagonal slices only; Gaussian kernel (a width) on log values",
    "paper": "Filip 2012 as published, isotropic: Gaussian kernel on linear values",
    "aniso-average": "all 8 slices, mean of the two slices (linear rule)",
    "aniso-crossing": "all 8 slices, sum less the crossing value (reproduces both slices)",
    "aniso-log": "all 8 slices, multiplicative rule (product over the crossing), log after it",
    "aniso": "all 8 slices, eq. (2-4) min-max stretch (filip2012); the recommended anisotropic model",
    "paper-aniso": "Filip 2012 as published, anisotropic: eq. (2-4), Gaussian on linear values",
}
#: The named models, in complexity order (rank = position; see the module docstring).
CANDIDATES: dict[str, Candidate] = {
    name: Candidate(name, settings, rank, _DESCRIPTIONS[name])
    for rank, (name, settings) in enumerate(_SETTINGS.items())
}
#: Candidates tried by default: the budget and the subspace rule (one RBF factorisation).
DEFAULT_ISO = ("iso",)
#: ("aniso-log" is not among them: in the log of the samples "aniso-crossing" is the
#: multiplicative rule, and its own value space would be one more RBF factorisation.)
DEFAULT_ANISO = ("iso", "aniso-average", "aniso-crossing", "aniso")
#: Optional kernel-family candidates (each family is one more compilation).
KERNEL_FAMILY = ("iso", "iso-linear", "iso-gaussian")
TOL = MODEL_TOL
#: The prior-only model (:mod:`abrdf_jax.prior`; ``reconstruct --model prior``): a candidate of
#: the automatic choice when a prior is given. It ranks above every RBF model: it brings the
#: most assumptions that the measurement does not hold (a database's materials), so it is chosen
#: only where its held-out error beats every RBF model's by more than the tolerance ("no more
#: than a scene needs"; docs/model_selection.md).
PRIOR = "prior"
PRIOR_RANK = len(CANDIDATES)
PRIOR_DESCRIPTION = (
    "a learned prior alone (Nielsen et al. 2015 PCA, ridge fit of the mapped samples); the "
    "slices of the budget"
)


#: The fused model (``reconstruct --model fused``): the prior plus a stationary kernel on its
#: residual, at the prior's fixed hyper-parameters. It ranks above the prior alone (it adds a
#: kernel to the prior's assumptions): chosen only where it beats the prior and every RBF model
#: by more than the tolerance.
FUSED = "fused"
FUSED_RANK = PRIOR_RANK + 1
FUSED_DESCRIPTION = (
    "a learned prior plus a stationary kernel on its residual (regression kriging, fixed "
    "hyper-parameters); the slices of the budget"
)
#: The models that read a prior: name -> (rank, description).
LEARNED = {PRIOR: (PRIOR_RANK, PRIOR_DESCRIPTION), FUSED: (FUSED_RANK, FUSED_DESCRIPTION)}


#: The bivariate ``(θh, θd)`` model (:func:`abrdf_jax.reconstruct_bivariate`): what the automatic
#: choice gives an isotropic material (the isotropy test's verdict, or no axial slices). Where
#: there is a comparison (beside a prior's models), ``iso`` (an RBF, which has held-out errors)
#: is scored in its place and stands for the isotropic models; chosen, it gives the bivariate
#: model (on every slice of the budget; :func:`abrdf_jax.select._choice.finish`). Among the
#: anisotropic candidates ``iso`` stays the RBF: on the analytic anisotropic captures of
#: ``python -m benchmarks.captures`` the bivariate model in its place was better on some
#: materials and worse on others, and made denser slices worse on average. Its own held-out
#: error is not computed: on the MERL train split it was below ``iso``'s for every material
#: (notes, nineteenth session), and its table is better than ``iso``'s on 49 of the 54 MERL
#: test materials (``python -m benchmarks.bivariate``). It ranks below every RBF model.
BIVARIATE = "bivariate"
BIVARIATE_RANK = -1
BIVARIATE_DESCRIPTION = (
    "a thin-plate spline of the log BRDF in (sqrt(theta_h), theta_d) (Romeiro et al. 2008): an "
    "isotropic material as a function of two angles; every slice of the budget"
)


def description(name: str) -> str:
    """What a model of the choice is (an RBF candidate, the bivariate model, the prior or the
    fused model)."""
    if name == BIVARIATE:
        return BIVARIATE_DESCRIPTION
    return LEARNED[name][1] if name in LEARNED else CANDIDATES[name].description


def rank_of(name: str) -> int:
    """The complexity rank of any model of the choice (RBF candidates, the bivariate model, the
    learned models)."""
    if name == BIVARIATE:
        return BIVARIATE_RANK
    return LEARNED[name][0] if name in LEARNED else candidate(name).rank


def candidate(name: str) -> Candidate:
    """A named candidate; :class:`InputError` listing the names otherwise."""
    if name not in CANDIDATES:
        raise InputError(f"unknown model {name!r}; choose auto or one of: {', '.join(CANDIDATES)}")
    return CANDIDATES[name]
