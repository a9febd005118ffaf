"""Automatic model selection: the simplest reconstruction model that the measurements support.

::

    import abrdf_jax as aj
    from abrdf_jax import select

    report = select.isotropy_test(samples)            # noise-aware test on the axial slices
    sel = select.select_model(samples)                # isotropy, then held-out error + 5 % rule
    sels = select.select_models(many)                 # the same for many, folds batched
    print(sel.name, sel.reason, sel.errors)
    table = aj.reconstruct(samples, sel.config, sel.params)

    curve = select.sample_count_curve(material)       # how few samples per slice suffice?

See :mod:`abrdf_jax.select._isotropy` (the test) and :mod:`abrdf_jax.select._select` (candidates, ranks,
held-out errors, the tolerance rule).
"""

from ._isotropy import (
    LEVEL as LEVEL,
    MIN_EFFECT as MIN_EFFECT,
    IsotropyReport as IsotropyReport,
    isotropy_batch as isotropy_batch,
    chi2_sf as chi2_sf,
    estimate_noise as estimate_noise,
    isotropy_test as isotropy_test,
)
from ._select import (
    CANDIDATES as CANDIDATES,
    DEFAULT_ANISO as DEFAULT_ANISO,
    DEFAULT_ISO as DEFAULT_ISO,
    KERNEL_FAMILY as KERNEL_FAMILY,
    TOL as TOL,
    Candidate as Candidate,
    Selection as Selection,
    candidate as candidate,
    fold_data as fold_data,
    group_configs as group_configs,
    held_out_errors as held_out_errors,
    held_out_errors_batch as held_out_errors_batch,
    select_model as select_model,
    tolerance_choice as tolerance_choice,
)
from ._batch import select_models as select_models
from ._samplecount import (
    DEFAULT_COUNTS as DEFAULT_COUNTS,
    SampleCountCurve as SampleCountCurve,
    sample_count_curve as sample_count_curve,
)
