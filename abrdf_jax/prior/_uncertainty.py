"""The predictive uncertainty of the command line's learned models (``--model fused|prior``) as
a Gaussian process: their hyper-parameters, and the table with its standard deviation.

Both models are the fused model of :mod:`abrdf_jax.prior._fused`:

- ``"fused"``: the prior's fixed hyper-parameters (:func:`~abrdf_jax.prior._fused.prior_fused`:
  the file's own, else :data:`~abrdf_jax.prior.FUSED_DEFAULTS`), reference interpolated as they
  say;
- ``"prior"``: the limit ``σ_k → 0`` (no kernel) with ``σ_p = 1`` (the prior as trained) and
  ``σ_n² = λ`` (the prior's own ridge λ), reference interpolated linearly: its posterior mean is
  :func:`~abrdf_jax.prior.reconstruct_prior` (tests/test_fused.py), what ``--model prior`` runs.

The hyper-parameters of the command line were chosen for the mean (the mean depends on the
ratios of the scales only), so the variance's overall scale means nothing until it is fitted:
:func:`reconstruct_with_std` scales ``σ_p, σ_k, σ_n`` by each measurement's maximum-evidence
amplitude (:func:`~abrdf_jax.prior._fused.rescaled`; the table does not change). The standard
deviation is the latent (noise-free) one, in the prior's mapped space: the natural log of
``x cos θv + ε`` (``x`` a table value, ``θv`` the view elevation, ``ε`` the prior's floor), so the
``±kσ`` band of a value ``x`` is ``((x cos θv + ε) e^{±kσ} − ε) / cos θv``
(:func:`~abrdf_jax.prior.fused_band`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._errors import InputError
from .._names import VARIANCE_MODELS
from .._measurements import Measurements
from ._covariance import FusedHyper
from ._fused import reconstruct_fused, rescaled, prior_fused
from ._model import Prior


def learned_hyper(prior: Prior, model: str = "fused", dtype=None) -> tuple[FusedHyper, str]:
    """``(hyper, reference)`` of ``--model fused`` or ``--model prior`` as a fused model (module
    docstring).

    Raises:
        InputError: ``model`` is not one of :data:`VARIANCE_MODELS`.
    """
    if model not in VARIANCE_MODELS:
        raise InputError(
            f"model {model!r} has no predictive variance; use one of {', '.join(VARIANCE_MODELS)}"
        )
    hyper, settings = prior_fused(prior, dtype)
    if model == "fused":
        return hyper, settings["reference"]
    dt = hyper.log_sigma_p.dtype
    logs = (jnp.zeros((), dt), jnp.asarray(-jnp.inf, dt), 0.5 * jnp.log(jnp.asarray(prior.lam, dt)))
    no_kernel = eqx.tree_at(lambda h: (h.log_sigma_p, h.log_sigma_k, h.log_sigma_n), hyper, logs)
    return no_kernel, "linear"


@eqx.filter_jit
def reconstruct_with_std(
    meas: Measurements, prior: Prior, model: str = "fused", alpha=None, *, rescale: bool = True
):
    """The table(s) of ``--model fused`` or ``--model prior`` and their predictive standard
    deviation (module docstring).

    Args:
        meas: one :class:`~abrdf_jax.Measurements` ``(S, nmax)`` or a stack ``(B, S, nmax)``.
        prior: a :class:`~abrdf_jax.prior.Prior`.
        model: ``"fused"`` (default) or ``"prior"``.
        alpha: slice offset α in radians (default the protocol's 15°); scalar or ``(B,)``.
        rescale: scale the variance to each measurement's samples (maximum evidence); ``False``
            keeps the fixed hyper-parameters' own scale.

    Returns:
        ``(tables, std)``, both ``(..., 81, 81, 3)``: the tables (as :func:`reconstruct_fused`)
        and the latent standard deviation of ``ln(x cos θv + ε)`` per direction pair and
        channel (non-negative; equal over the channels of a ``"shared"`` prior).
    """
    hyper, reference = learned_hyper(prior, model, prior.dtype)
    if rescale:
        hyper = rescaled(meas, prior, hyper, alpha, reference=reference)
    table, var = reconstruct_fused(
        meas, prior, hyper, alpha, reference=reference, return_variance=True
    )
    return table, jnp.sqrt(var)
