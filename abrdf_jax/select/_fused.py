"""Held-out error of the fused model: the same folds, residual and ε as the RBF candidates and
the prior (:mod:`abrdf_jax.select._prior`).

Fold ``j`` conditions the fused model (:mod:`abrdf_jax.prior._fused`: prior mean and low-rank
covariance, a stationary kernel on the residual, noise; fixed hyper-parameters) on the training
samples of the budget's slices and predicts every held-out sample by its posterior mean at that
sample's position, through the inverse map; the error is :func:`abrdf_jax._folds.log_rms` over
folds, held-out samples and channels, as for every other candidate. Folds and materials are
mapped one after the other (``lax.map``: a vmapped Cholesky solve deadlocks jaxlib 0.10.2's CPU
thread pool, docs/prior.md).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._measurements import Measurements
from ..prior._covariance import FusedHyper, covariance
from ..prior._fused import _kron_eye, factor, fused_basis, prior_fused, sample_features
from ._prior import affine_map, fold_error, predict, prior_fold_data


def fused_map(prior, hyper: FusedHyper, train: Measurements, test: Measurements, alpha, ref):
    """The fused posterior mean given ``train``'s samples, at ``test``'s positions, as the fold's
    :class:`~abrdf_jax.select._prior.HeldOutMap`: ``gain = cov(test, train) C⁻¹ W``."""
    dt = prior.dtype
    basis = fused_basis(prior, train, alpha, ref)
    x_s = sample_features(hyper, train, alpha).astype(dt)
    fs = factor(hyper, basis, x_s)
    out = fused_basis(prior, test, alpha, ref)
    k_ts = _kron_eye(
        covariance(hyper, sample_features(hyper, test, alpha).astype(dt), x_s), basis.width
    )
    cov = hyper.sigma_p.astype(dt) * (out.components @ fs.u.T)
    cov = cov + hyper.sigma_k.astype(dt) ** 2 * k_ts * fs.weight[None, :]
    gain = fs.solve(cov.T).T * fs.weight[None, :]  # C⁻¹ is symmetric: cov C⁻¹ = (C⁻¹ covᵀ)ᵀ
    return affine_map(prior, gain, basis, out)


def fused_predict(prior, hyper: FusedHyper, train: Measurements, test: Measurements, alpha, ref):
    """The fused posterior mean given ``train``'s samples, at ``test``'s positions: ``(P, 3)``."""
    hm = fused_map(prior, hyper, train, test, alpha, ref)
    s, n = train.t.shape
    y = jnp.reshape(train.y, (s * n, 3)).astype(prior.dtype)
    return predict(hm, y, prior.eps, 3 if prior.channels == "joint" else 1)


def _held_out(data: dict, prior, hyper, ref):
    train, test, alpha = data["train"], data["test"], data["alpha"]
    pred = jax.lax.map(
        lambda tt: fused_predict(prior, hyper, tt[0], tt[1], alpha, ref), (train, test)
    )
    return fold_error(pred, data)


_held_out_jit = eqx.filter_jit(_held_out)


def fused_held_out_errors(data: list[dict], prior, hyper, ref: str = "log") -> list[float]:
    """Held-out RMS log errors of the fused model for materials of one layout (``data``:
    :func:`abrdf_jax.select._prior.prior_fold_data` of each): one compile, one call per
    material (a padded ``lax.map`` batch would fit the padding too)."""
    return [float(_held_out_jit(d, prior, hyper, ref)) for d in data]


def fused_held_out_error(
    meas: Measurements, prior, alpha, k: int = 4, budget="aniso204", fused=None
):
    """The held-out RMS log error of the fused model on one measurement (module docstring);
    ``fused``: ``(FusedHyper, settings)`` (default the prior's own,
    :func:`abrdf_jax.prior._fused.prior_fused`)."""
    hyper, settings = prior_fused(prior) if fused is None else fused
    data = prior_fold_data(meas, alpha, k, budget)
    return float(_held_out_jit(data, prior, hyper, settings["reference"]))


def fused_of(prior, fused):
    """The fused candidate of a selection: ``None`` (no prior, or ``fused=False``), else
    ``(FusedHyper, settings)``: the prior's own (``fused=True``) or a given :class:`FusedHyper`
    (reference interpolated in the log domain)."""
    if prior is None or fused is False:
        return None
    if fused is True:
        return prior_fused(prior)
    if not isinstance(fused, FusedHyper):
        raise TypeError(f"fused must be True, False or a FusedHyper, got {type(fused).__name__}")
    return fused, {**fused.as_dict(), "reference": "log"}
