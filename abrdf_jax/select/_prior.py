"""Held-out error of the prior-only model: the same folds, residual and ε as the RBF candidates.

Fold ``j`` (:func:`abrdf_jax._folds.sample_folds`) fits the prior's weights to the training
samples of the budget's slices (:func:`abrdf_jax.prior.ridge_operator` on the prior at those
positions) and predicts every held-out sample (the prior at the held-out positions, through the
inverse map); the error is the RMS log residual of :func:`abrdf_jax._folds.log_rms` with the
measurement's ε, over folds, held-out samples and channels: the number
:func:`abrdf_jax.select.held_out_errors` gives an RBF candidate, so the tolerance rule compares
like with like. One compiled, vmapped call per layout for a batch of materials
(:func:`prior_held_out_errors_batch`), as :func:`abrdf_jax.select.select_models` does.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._config import Config
from .._folds import log_rms, sample_folds
from .._measurements import Measurements
from .._values import measurement_eps
from ..prior._reconstruct import ridge_operator, sample_basis


def prior_fold_data(meas: Measurements, alpha, k: int = 4, budget: str = "aniso204") -> dict:
    """The folds of one measurement for the prior: ``train`` and ``test`` :class:`Measurements`
    with a leading fold axis (``iso102``: the axial slices are not trained on; every held-out
    sample is predicted), ``res_eps`` ``(3,)`` and ``alpha`` (radians)."""
    train, tt, ty, tm = sample_folds(meas, k)
    if budget == "iso102":
        count = np.asarray(train.count).copy()
        count[:, 0::2] = 0
        train = train.replace(count=jnp.asarray(count, train.count.dtype))
    test = meas.replace(t=tt, y=ty, count=jnp.sum(tm, axis=-1).astype(meas.count.dtype))
    return {
        "train": train,
        "test": test,
        "res_eps": measurement_eps(meas, Config().log_eps),  # the RBF candidates' ε
        "alpha": jnp.asarray(alpha, meas.y.dtype),
    }


class HeldOutMap(NamedTuple):
    """One fold's prediction of a learned model as an affine map of its training samples' log
    values (``w`` = 1 for a ``shared`` prior, one row per channel; 3 for ``joint``, rows of
    ``P·3``): ``m = gain · ln(max(y, 0) cos θv,train + ε) + offset``, prediction
    ``max((exp(m) − ε) / cos θv,test, 0)`` (the inverse map, the reference folded into
    ``offset``). The JAX held-out errors and the numpy entries of the command line
    (:mod:`abrdf_jax.select._learned_entry`) both predict through it.

    Attributes:
        gain: ``(P_test·w, P_train·w)``; offset: ``(P_test·w,)``.
        cos_train: ``(P_train·w,)``; cos_test: ``(P_test·w,)``.
    """

    gain: object
    offset: object
    cos_train: object
    cos_test: object


def affine_map(prior, gain, basis, out) -> HeldOutMap:
    """The :class:`HeldOutMap` of a fold whose mapped prediction is ``gain`` times the centred
    mapped training samples plus the prior's mean at the held-out positions (``basis``/``out``:
    the prior at the training/held-out positions)."""
    eps = prior.eps
    shift = jnp.log(basis.reference * basis.cos_v + eps) + basis.mean
    offset = out.mean + jnp.log(out.reference * out.cos_v + eps) - gain @ shift
    return HeldOutMap(gain, offset, basis.cos_v, out.cos_v)


def prior_map(prior, train: Measurements, test: Measurements, lam, alpha) -> HeldOutMap:
    """The prior fitted to ``train``'s samples (ridge weights), at ``test``'s positions."""
    basis = sample_basis(prior, train, alpha)
    out = sample_basis(prior, test, alpha)
    return affine_map(prior, out.components @ ridge_operator(basis, lam), basis, out)


def predict(hm: HeldOutMap, y, eps: float, width: int):
    """The prediction ``(P_test, 3)`` of training values ``y`` ``(P_train, 3)`` (numpy or JAX)."""
    xp = np if isinstance(hm.gain, np.ndarray) else jnp
    z = y.reshape(-1, 1) if width == 3 else y  # rows of the map, one column per right side
    x = xp.log(xp.maximum(z, 0) * hm.cos_train[:, None] + eps)
    m = hm.gain @ x + hm.offset[:, None]
    return xp.maximum((xp.exp(m) - eps) / hm.cos_test[:, None], 0).reshape(-1, 3)


def _predict(prior, train: Measurements, test: Measurements, lam, alpha):
    """The prior fitted to ``train``'s samples, at ``test``'s positions: ``(P_test, 3)``."""
    hm = prior_map(prior, train, test, lam, alpha)
    return predict(hm, train.y.reshape(-1, 3), prior.eps, 3 if prior.channels == "joint" else 1)


def _held_out(data: dict, prior, lam):
    train, test = data["train"], data["test"]
    alpha = data["alpha"]
    pred = jax.vmap(lambda a, b: _predict(prior, a, b, lam, alpha))(train, test)
    return fold_error(pred, data)


def fold_error(pred, data: dict):
    """The held-out RMS log error of predictions ``(k, P_test, 3)`` at the held-out samples of
    :func:`prior_fold_data`'s folds (the RBF candidates' residual and ε)."""
    test = data["test"]
    k = pred.shape[0]
    y = test.y.reshape(k, -1, 3)
    mask = test.mask.reshape(k, -1, 1)
    return log_rms(pred, y, data["res_eps"], mask)


_held_out_jit = eqx.filter_jit(_held_out)


@eqx.filter_jit
def prior_held_out_errors_batch(data: dict, prior, lam):
    """Held-out RMS log errors ``(B,)`` of the prior for a batch of materials (``data``:
    :func:`prior_fold_data` of each, stacked along a leading axis; one layout)."""
    return jax.vmap(lambda d: _held_out(d, prior, lam))(data)


def prior_held_out_error(
    meas: Measurements, prior, alpha, k: int = 4, budget: str = "aniso204", lam=None
) -> float:
    """The held-out RMS log error of the prior-only model on one measurement (module docstring)."""
    lam = prior.lam if lam is None else lam
    return float(_held_out_jit(prior_fold_data(meas, alpha, k, budget), prior, lam))
