"""Held-out folds of one measurement and the held-out residual (the one copy).

Self-calibration (:mod:`abrdf_jax.tuning`), model selection and the sample-count curve
(:mod:`abrdf_jax.select`) all score a reconstruction by predicting samples it did not see:

- :func:`sample_folds`: fold ``j`` holds out samples ``j, j+k, …`` of every slice;
- :func:`held_out_directions`: the unit vectors of held-out slice positions;
- :func:`log_residual` / :func:`log_rms`: ``ln(pred + ε) − ln(y + ε)`` on the held-out samples,
  scale free like the protocol's LogErr, with ``ε = log_eps · mean sample`` of the measurement
  (:func:`abrdf_jax._values.measurement_eps`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._errors import InputError
from ._measurements import Measurements
from ._slices import slice_vectors


def sample_folds(meas: Measurements, k: int):
    """``k`` folds: fold ``j`` holds out samples ``j, j+k, ...`` of every slice (numpy, concrete).

    Returns:
        ``(train, test_t, test_y, test_mask)``: ``train`` a :class:`Measurements` with a leading
        fold axis; ``test_t`` ``(k, S, ntest)``, ``test_y`` ``(k, S, ntest, 3)``, ``test_mask``
        ``(k, S, ntest)``.

    Raises:
        InputError: ``k < 2``. A slice that would keep fewer than 3 samples in a fold holds
        none out (it is in every fold's training data).
    """
    if not (isinstance(k, int) and k >= 2):
        raise InputError(f"k (folds) must be an int >= 2, got {k!r}")
    t, y, cnt = np.asarray(meas.t), np.asarray(meas.y), np.asarray(meas.count)
    S, nmax = t.shape
    train_t, train_y, train_c, test_t, test_y, test_m = [], [], [], [], [], []
    ntest = -(-nmax // k)
    for j in range(k):
        tt, yy, cc = np.zeros_like(t), np.zeros_like(y), np.zeros(S, np.int32)
        et, ey, em = (
            np.zeros((S, ntest), t.dtype),
            np.zeros((S, ntest, 3), y.dtype),
            np.zeros((S, ntest), bool),
        )
        for s in range(S):
            n = int(cnt[s])
            idx = np.arange(n)
            held = idx[idx % k == j]
            kept = idx[idx % k != j]
            if n and len(kept) < 3:  # too short to spare a sample: kept whole, never held out
                held, kept = idx[:0], idx
            tt[s, : len(kept)], yy[s, : len(kept)], cc[s] = t[s, kept], y[s, kept], len(kept)
            if n:
                et[s, : len(held)], ey[s, : len(held)], em[s, : len(held)] = (
                    t[s, held],
                    y[s, held],
                    True,
                )
        train_t.append(tt), train_y.append(yy), train_c.append(cc)
        test_t.append(et), test_y.append(ey), test_m.append(em)
    train = meas.replace(
        t=jnp.asarray(np.stack(train_t)),
        y=jnp.asarray(np.stack(train_y)),
        count=jnp.asarray(np.stack(train_c)),
    )
    return (
        train,
        jnp.asarray(np.stack(test_t)),
        jnp.asarray(np.stack(test_y)),
        jnp.asarray(np.stack(test_m)),
    )


def held_out_directions(test_t, pairs, alpha):
    """Unit vectors ``(wi, wv)``, each ``(S · n, 3)``, of slice positions ``test_t`` ``(S, n)``.

    Slice ``s`` is the axial (even) or diagonal (odd) slice of ``pairs[s // 2]``; ``alpha`` in
    radians (traced: differentiable).
    """
    wi, wv = zip(
        *(slice_vectors(test_t[s], s % 2, pairs[s // 2], alpha) for s in range(test_t.shape[0]))
    )
    return jnp.concatenate(wi), jnp.concatenate(wv)


def log_residual(pred, y, eps, mask):
    """``ln(max(pred, 0) + ε) − ln(max(y, 0) + ε)`` where ``mask``, else 0 (``mask`` broadcasts)."""
    r = jnp.log(jnp.maximum(pred, 0.0) + eps) - jnp.log(jnp.maximum(y, 0.0) + eps)
    return jnp.where(mask, r, 0.0)


def log_rms(pred, y, eps, mask, axis=None):
    """RMS of :func:`log_residual` over the masked entries (and the channels) along ``axis``."""
    r = log_residual(pred, y, eps, mask)
    n = jnp.sum(jnp.broadcast_to(mask, r.shape), axis=axis)
    return jnp.sqrt(jnp.sum(r * r, axis=axis) / jnp.maximum(n, 1))
