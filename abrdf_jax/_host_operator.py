"""The operators the command line applies without JAX, as a public function (benchmarks, users
who serve many materials of one layout from numpy).

:func:`compile_numpy_operator` builds the numpy form of a reconstruction for one sample layout:
for a linear :class:`~abrdf_jax.Config` the RBF operator (:func:`abrdf_jax.compile_operator`'s
single-stage matrix, built in float64, stored float32), for a :class:`abrdf_jax.prior.Prior` the
prior-only model (map → matrix → inverse map; docs/prior.md), or with ``fused`` the fused model
(prior + kernel on the residual at fixed hyper-parameters; one matrix). All have ``apply(y)``:
``(..., S, nmax, 3)`` sample values → ``(..., 81, 81, 3)`` float32 tables. Building imports JAX.
"""

from __future__ import annotations

from ._config import Config, default_values
from ._errors import InputError


def compile_numpy_operator(
    model, meas, params=None, *, budget: str | None = None, lam=None, fused=False
):
    """The numpy operator of ``model`` at ``meas``'s layout (module docstring).

    Args:
        model: a linear :class:`~abrdf_jax.Config` or a :class:`abrdf_jax.prior.Prior`.
        meas: one :class:`~abrdf_jax.Measurements` (its slice positions and counts).
        params: :class:`~abrdf_jax.Params` (default: the model's defaults at the protocol α);
            the prior reads only α.
        budget: the prior's slices: ``"iso102"`` the diagonal ones only; default all of them.
        lam: the prior's ridge λ (default its own).
        fused: for a prior, ``True``: the fused model at the prior's own hyper-parameters (its
            metadata's ``"fused"``, else the package's defaults); a dict: those settings
            (``abrdf_jax.prior`` docs, "Fused model on the command line"); ``False``: the prior
            alone.

    Raises:
        InputError: a nonlinear configuration, or a model of another kind.
    """
    from ._cache import build_entry

    if isinstance(model, Config):
        params = default_values(model) if params is None else params
        return build_entry(meas, model, params)
    if not hasattr(model, "components"):
        raise InputError(f"model must be a Config or a Prior, got {type(model).__name__}")
    from ._prior_operator import build_prior_entry, slice_counts

    alpha = default_values().alpha if params is None else params.alpha
    if fused is not False:
        from ._fused_operator import build_fused_entry
        from .prior._fused_settings import check_fused, fused_settings

        settings = fused_settings(model.metadata) if fused is True else dict(fused)
        problem = check_fused(settings)
        if problem:
            raise InputError(f"fused: {problem}")
        settings.setdefault("reference", "log")
        return build_fused_entry(model, meas, alpha, settings, slice_counts(meas, budget))
    lam = float(model.lam) if lam is None else float(lam)
    return build_prior_entry(model, meas, alpha, lam, slice_counts(meas, budget))
