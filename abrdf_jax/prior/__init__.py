"""Learned priors of ABRDF tables (public API): train, store, load, reconstruct with one.

A prior in the style of Nielsen, Jensen & Ramamoorthi, "On Optimal, Minimal BRDF Sampling for
Reflectance Acquisition", ACM TOG 34(6), 2015: a log-relative map of the tables against the
database median, scaled principal components, and a ridge projection of a measurement's mapped
samples (docs/prior.md). :func:`default_prior` is trained on the package's own analytic
materials (no measured data ships, nothing is downloaded).

The names are loaded on first use (PEP 562), so ``from abrdf_jax import prior`` imports no JAX;
The fused model (:func:`reconstruct_fused`: the prior as the mean and low-rank covariance of a
Gaussian process, plus a stationary kernel on the residual and noise; its predictive variance;
hyper-parameters by evidence, :func:`fit_evidence`, or on a population, :func:`fit_population`)
is in docs/prior.md "Fused model".

reading a prior file's summary (:func:`prior_info`) needs numpy only.
"""

from __future__ import annotations

from .._lazy import lazy_exports

# public name -> private module that defines it (the one place this package's API is listed)
_EXPORTS = {
    "_mapping": (
        "CEILING_MARGIN",
        "CHANNELS",
        "DEFAULT_EPS",
        "NIELSEN_EPS",
        "PCA",
        "below_ceiling",
        "grid_cos_view",
        "inverse_log_relative",
        "log_relative",
        "mapped_rows",
        "median_reference",
        "pca_components",
    ),
    "_model": ("Prior", "SampleBasis", "assemble_prior", "basis_from_training", "train_prior"),
    "_file": ("PRIOR_FORMAT", "load_prior", "prior_info", "read_prior_file", "save_prior"),
    "_inputs": ("read_training_tables",),
    "_reconstruct": (
        "prior_at_samples",
        "project",
        "reconstruct_prior",
        "ridge_operator",
        "sample_basis",
    ),
    "_exact": ("TrainingModels", "exact_basis", "stack_models", "training_models"),
    "_select": ("cross_validate_prior", "select_prior", "table_samples"),
    "_default": (
        "DEFAULT_RECIPE",
        "default_prior",
        "default_training_models",
        "default_training_tables",
    ),
    "_covariance": ("COORDINATES", "COVARIANCES", "FusedHyper", "covariance"),
    "_fused": (
        "reconstruct_fused",
        "fused_evidence",
        "fused_band",
        "fused_coverage",
        "fused_rescaled",
    ),
    "_evidence": ("fit_evidence", "fit_population"),
    "_fused_settings": ("FUSED_DEFAULTS",),
    "_uncertainty": ("VARIANCE_MODELS", "learned_hyper", "reconstruct_with_std"),
    "_suggest": ("candidate_slices", "ring_pairs", "slice_scores", "suggest_slices"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS)
