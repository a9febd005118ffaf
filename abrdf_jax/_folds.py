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

import numpy as np

from ._errors import InputError


def _jnp():
    import jax.numpy as jnp

    return jnp


def fold_slots(count, nmax: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the samples of each fold come from: ``(train, test)``, int arrays ``(k, S, nmax)``
    and ``(k, S, ⌈nmax/k⌉)`` of the flat slot ``s · nmax + i`` of the measurement's sample that
    fold ``j`` trains on / holds out at each of its own slots, ``-1`` where the fold's slice
    ends (numpy, no JAX: the held-out operators of the command line read them too).

    Fold ``j`` holds out samples ``j, j+k, …`` of every slice; a slice that would keep fewer
    than 3 samples holds none out (it is in every fold's training data).

    Raises:
        InputError: ``k < 2``.
    """
    if not (isinstance(k, int) and k >= 2):
        raise InputError(f"k (folds) must be an int >= 2, got {k!r}")
    cnt = np.asarray(count)
    S = cnt.shape[0]
    ntest = -(-nmax // k)
    train = np.full((k, S, nmax), -1, np.int64)
    test = np.full((k, S, ntest), -1, np.int64)
    for j in range(k):
        for s in range(S):
            n = int(cnt[s])
            idx = np.arange(n)
            held, kept = idx[idx % k == j], idx[idx % k != j]
            if n and len(kept) < 3:  # too short to spare a sample: kept whole, never held out
                held, kept = idx[:0], idx
            train[j, s, : len(kept)] = s * nmax + kept
            test[j, s, : len(held)] = s * nmax + held
    return train, test


def gather(a, slots):
    """``a`` ``(S, nmax, ...)`` at flat slots ``slots`` (:func:`fold_slots`); zero where a
    fold's slice ends (slot ``-1``)."""
    flat = a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])[np.maximum(slots, 0)]
    return np.where((slots >= 0).reshape(*slots.shape, *([1] * (a.ndim - 2))), flat, 0)


def sample_folds(meas, k: int):
    """``k`` folds: fold ``j`` holds out samples ``j, j+k, ...`` of every slice (numpy, concrete).

    Returns:
        ``(train, test_t, test_y, test_mask)``: ``train`` a :class:`Measurements` with a leading
        fold axis; ``test_t`` ``(k, S, ntest)``, ``test_y`` ``(k, S, ntest, 3)``, ``test_mask``
        ``(k, S, ntest)``.

    Raises:
        InputError: ``k < 2``. A slice that would keep fewer than 3 samples in a fold holds
        none out (it is in every fold's training data).
    """
    jnp = _jnp()
    t, y, cnt = np.asarray(meas.t), np.asarray(meas.y), np.asarray(meas.count)
    train, test = fold_slots(cnt, t.shape[1], k)
    train_meas = meas.replace(
        t=jnp.asarray(gather(t, train).astype(t.dtype)),
        y=jnp.asarray(gather(y, train).astype(y.dtype)),
        count=jnp.asarray((train >= 0).sum(-1).astype(np.int32)),
    )
    return (
        train_meas,
        jnp.asarray(gather(t, test).astype(t.dtype)),
        jnp.asarray(gather(y, test).astype(y.dtype)),
        jnp.asarray(test >= 0),
    )


def held_out_directions(test_t, pairs, alpha, xp=None):
    """Unit vectors ``(wi, wv)``, each ``(S · n, 3)``, of slice positions ``test_t`` ``(S, n)``.

    Slice ``s`` is the axial (even) or diagonal (odd) slice of ``pairs[s // 2]``; ``alpha`` in
    radians (traced: differentiable). ``xp``: ``jax.numpy`` (default) or ``numpy``.
    """
    from ._slices import slice_vectors

    xp = xp or _jnp()
    wi, wv = zip(
        *(slice_vectors(test_t[s], s % 2, pairs[s // 2], alpha, xp) for s in range(test_t.shape[0]))
    )
    return xp.concatenate(wi), xp.concatenate(wv)


def log_residual(pred, y, eps, mask, xp=None):
    """``ln(max(pred, 0) + ε) − ln(max(y, 0) + ε)`` where ``mask``, else 0 (``mask`` broadcasts;
    ``xp``: ``jax.numpy`` by default, or ``numpy``)."""
    xp = xp or _jnp()
    r = xp.log(xp.maximum(pred, 0.0) + eps) - xp.log(xp.maximum(y, 0.0) + eps)
    return xp.where(mask, r, 0.0)


def log_rms(pred, y, eps, mask, axis=None, xp=None):
    """RMS of :func:`log_residual` over the masked entries (and the channels) along ``axis``."""
    xp = xp or _jnp()
    r = log_residual(pred, y, eps, mask, xp)
    n = xp.sum(xp.broadcast_to(mask, r.shape), axis=axis)
    return xp.sqrt(xp.sum(r * r, axis=axis) / xp.maximum(n, 1))
