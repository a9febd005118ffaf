"""The fused model on the operator path: its entry per layout, built from the library's own
posterior (:mod:`abrdf_jax.prior._fused`), and the model the command line runs.

``abrdf-jax reconstruct --model fused [--prior FILE|default]`` reconstructs with the fused model
(prior mean and low-rank covariance, a stationary kernel on the residual, noise) at the prior's
fixed hyper-parameters (:mod:`abrdf_jax.prior._fused_settings`: the file's own, else the
package's defaults chosen on MERL train). For one layout that is the numpy
:class:`~abrdf_jax._fused_entry.FusedEntry`, built once (JAX, float64, rounded to float32) and kept
in the operator store under :func:`abrdf_jax._prior_operator.prior_entry_key`: the prior-only
entry's key with kind ``"fused"`` and the hyper-parameters in place of λ. A stored entry is
applied without JAX.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ._fused_entry import FusedEntry
from ._prior_operator import LearnedModel, entry_layout, f32, float64_template, grid_lift

#: Version of the fused entry key; bump it when the entry changes meaning.
ENTRY_FORMAT = 2


@dataclasses.dataclass(frozen=True)
class FusedModel(LearnedModel):
    """The fused model of one budget: the prior (with its hyper-parameters) and the budget."""

    name = "fused"
    entry_kind = FusedEntry

    def key_doc(self) -> dict:
        s = self.source.fused_settings()
        numbers = {k: s[k] for k in ("coords", "kernel", "widths", "reference")}
        numbers |= {k: float(s[k]) for k in ("sigma_p", "sigma_k", "sigma_n")}
        return {"format": ENTRY_FORMAT, "fused": numbers}

    def build(self, template, params) -> FusedEntry:
        counts = self.slice_counts(template)
        settings = self.source.fused_settings()
        return build_fused_entry(self.source.load(), template, params.alpha, settings, counts)


def _grid_gain(prior, hyper, meas, alpha, reference: str, index):
    """``(Mᵀ, x_ref,s, cos θv,s, μ_s)`` on the valid samples ``index`` (jitted: one compile
    instead of an eager dispatch per operation)."""
    from .prior._fused import factor, fused_basis, grid_features, grid_sample_covariance
    from .prior._fused import sample_features

    basis = fused_basis(prior, meas, alpha, reference)
    x_g = grid_features(hyper, prior.dtype)
    fs = factor(hyper, basis, sample_features(hyper, meas, alpha).astype(prior.dtype), x_g)
    gain = grid_sample_covariance(prior, hyper, fs)  # (D, N): cov(grid, samples)
    rows = basis.rows(index)  # the valid samples' rows
    mt = fs.solve(gain.T)[rows]  # C⁻¹ is symmetric: C⁻¹ gainᵀ = Mᵀ, (n_w, D)
    return mt, basis.reference[rows], basis.cos_v[rows], basis.mean[rows]


@functools.cache
def _jitted_gain():
    from ._build_jit import build_jit  # built once per layout: compiled cheaply

    return build_jit(_grid_gain)


def build_fused_entry(prior, meas, alpha, settings: dict, counts) -> FusedEntry:
    """The :class:`FusedEntry` of ``prior`` with the fused ``settings`` at ``meas``'s layout (α in
    radians), reading the samples within ``counts`` per slice; computed in float64 (JAX) from
    the library's factorisation (:func:`abrdf_jax.prior._fused.factor`), stored as float32."""
    import jax.numpy as jnp

    from ._cache import x64_scope
    from .prior._covariance import FusedHyper

    with x64_scope(True):
        f64 = jnp.float64
        p = prior.astype(f64)
        index, m = float64_template(meas, counts)
        out = _jitted_gain()(p, FusedHyper.from_settings(settings, f64), m, jnp.asarray(alpha, f64), settings["reference"],
                   jnp.asarray(index))  # fmt: skip
        mt, ref_s, cos_s, mean_s = (np.asarray(v, np.float64) for v in out)
        ref_g, cos_g = (np.asarray(v, np.float64) for v in p.grid_layout())
        mean_g = np.asarray(p.mean)
    eps = float(prior.eps)
    offset = mean_g + grid_lift(ref_g, cos_g, eps)
    offset = offset - (np.log(ref_s * cos_s + eps) + mean_s) @ mt
    return FusedEntry(
        matrix=f32(np.concatenate([mt, offset[None, :]], 0)),
        **entry_layout(prior, index, meas, cos_s, ref_g, cos_g),
    )
