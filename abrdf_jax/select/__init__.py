"""Automatic model selection: the simplest reconstruction model that the measurements support.

::

    import abrdf_jax as aj
    from abrdf_jax import select

    report = select.isotropy_test(samples)            # noise-aware test on the axial slices
    sel = select.select_model(samples)                # isotropy, then held-out error + 5 % rule
    sels = select.select_models(many)                 # the same for many, folds batched
    print(sel.name, sel.reason, sel.errors)          # "bivariate" for an isotropic material
    table = sel.reconstruct(samples)                  # the chosen model's table

    curve = select.sample_count_curve(material)       # how few samples per slice suffice?

See :mod:`abrdf_jax.select._isotropy` (the test) and :mod:`abrdf_jax.select._select` (candidates, ranks,
held-out errors, the tolerance rule).
"""

from .._lazy import lazy_exports

# public name -> private module that defines it; loaded on first use (PEP 562): the candidates,
# the isotropy test and the choice of one candidate need no JAX (the command line's warm path)
_EXPORTS = {
    "_isotropy": (
        "LEVEL",
        "MIN_EFFECT",
        "IsotropyReport",
        "isotropy_batch",
        "estimate_noise",
        "isotropy_test",
    ),
    "_chi2": ("chi2_sf",),
    "_candidates": (
        "BIVARIATE",
        "CANDIDATES",
        "DEFAULT_ANISO",
        "DEFAULT_ISO",
        "KERNEL_FAMILY",
        "TOL",
        "Candidate",
        "candidate",
        "rank_of",
    ),
    "_choice": ("Selection", "group_configs", "quick_selection", "tolerance_choice"),
    "_select": (
        "fold_data",
        "held_out_errors",
        "held_out_errors_batch",
        "select_model",
    ),
    "_batch": ("select_models",),
    "_samplecount": ("DEFAULT_COUNTS", "SampleCountCurve", "sample_count_curve"),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS)
