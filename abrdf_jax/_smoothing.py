"""Noise-driven slice smoothing: a shrink of every sample towards its neighbours' interpolation.

A noisy sample enters the reconstruction twice: the slice interpolation reads it into the
subspaces the RBF fits, and the restored subspaces go back at their grid pairs as they are
(the paper's step 3), so a larger RBF λ smooths neither (``python -m benchmarks.capture_ablations``
measured it). So the *slices* are smoothed, in the space the slice interpolation sees (the log
of the samples, value space ``"logsamples"``), before the spike cap and the subspace rule:

    z_k ← z_k − β_s · r_k,    r_k = z_k − (w_l · z_{k−1} + w_r · z_{k+1})

with ``r_k`` the residual of sample ``k`` against the linear interpolation of its two periodic
neighbours on its slice ``s`` (weights from the sample positions). With independent noise of
variance ``σ²`` on locally linear data the shrink leaves ``σ² ((1 − β)² + β² (w_l² + w_r²))``
(``σ²/3`` at ``β = 2/3``, uniform spacing); a peak's own curvature is what it costs (``β r_k``).

``Config.slice_smoothing`` is a fixed ``β`` (a float, for comparisons) or the noise-driven rule
``(β_max, floor, scale)``. The rule estimates each material's noise as
:func:`abrdf_jax.select.estimate_noise` does, in the reconstruction's own log values:
``σ̂ = 1.4826 · median |r_k| / sqrt(1 + w_l² + w_r²)`` over every sample of every slice with ≥ 3
samples and every channel. On a slice whose samples are ``Δ_s`` apart a noise-free material's
own curvature already reads as ``floor · q_s`` with ``q_s = (Δ_s / Δ_0)²`` (the residual of a smooth
curve scales as the spacing squared; ``Δ_0 = 2π/26``, the protocol's diagonal slice: 0.021 there
on noise-free MERL test captures, 0.0013 at 100 samples a slice: the "rule's σ̂" column of
``benchmarks/results/noise_smoothing_test.md``), so the noise
variance is ``σ_n² = max(σ̂² − (floor · q_s)², 0)`` and

    β_s = β_max · σ_n² / (σ_n² + (scale · q_s)²)

a Wiener weight (noise variance against noise plus the variance of what a shrink would take
from the signal, which scales with the curvature too). A clean capture gets ``β ≈ 0``, a
sparse slice needs much more noise than a dense one before it is smoothed. The constants were
chosen on the MERL train split (``python -m benchmarks.noise_smoothing``, docs/captures.md
"Noise"). ``β`` depends on the material only through ``σ̂``; for given ``β`` the shrink is linear
in the samples, so the compiled operator applies it too (one sparse pass per material before its
matrix product: ``_operator.py``, ``_operator_entry.py``).

Every function takes ``xp`` (``jax.numpy``, the default, or ``numpy`` for the JAX-free operator
entry) and works on the padded slice layout ``(..., S, nmax, C)`` of :class:`Measurements`.
"""

from __future__ import annotations

import numpy as np

#: The spacing ``Δ_0`` (radians) at which the rule's ``floor`` and ``scale`` are given: the
#: protocol's diagonal slices (26 samples).
SPACING_0 = 2.0 * np.pi / 26
_MAD_TO_SIGMA = 1.4826
_TWO_PI = 2.0 * np.pi


def neighbours(t, count, xp=None):
    """``(left, right, wl, wr, valid)`` of every slot of a padded slice layout.

    Args:
        t: slice parameters ``(..., S, nmax)`` (radians, sorted within each slice).
        count: valid samples per slice ``(..., S)``.

    Returns:
        Neighbour indices ``(..., S, nmax)`` (periodic within the first ``count`` slots), the
        interpolation weights of the left and right neighbour, and ``valid``: the slot is a
        sample of a slice with at least 3 samples (only those are smoothed and enter ``σ̂``).
    """
    if xp is None:
        import jax.numpy as xp
    nmax = t.shape[-1]
    k = xp.arange(nmax)
    n = xp.asarray(count)[..., None]
    n1 = xp.maximum(n, 1)
    left = (k - 1) % n1
    right = (k + 1) % n1
    tl = xp.take_along_axis(t, left, axis=-1) - xp.where(k == 0, _TWO_PI, 0.0)
    tr = xp.take_along_axis(t, right, axis=-1) + xp.where(k == n - 1, _TWO_PI, 0.0)
    span = tr - tl
    ok = span > 0
    wr = xp.where(ok, (t - tl) / xp.where(ok, span, 1.0), 0.5)
    valid = (k < n) & (n >= 3)
    return left, right, (1.0 - wr).astype(t.dtype), wr.astype(t.dtype), valid


def residuals(z, nb, xp=None):
    """``r_k = z_k − (w_l z_{k−1} + w_r z_{k+1})`` of values ``z`` ``(..., S, nmax, C)``
    (0 at slots that are not ``valid``)."""
    if xp is None:
        import jax.numpy as xp
    left, right, wl, wr, valid = nb
    lead = (1,) * (z.ndim - 1 - left.ndim)  # the layout may be shared by a batch of values
    zl = xp.take_along_axis(z, left.reshape(*lead, *left.shape, 1), axis=-2)
    zr = xp.take_along_axis(z, right.reshape(*lead, *right.shape, 1), axis=-2)
    r = z - (wl[..., None] * zl + wr[..., None] * zr)
    return xp.where(valid[..., None], r, 0.0)


def noise_level(z, nb, xp=None):
    """``σ̂`` ``(...)``: ``1.4826 · median |r| / sqrt(1 + w_l² + w_r²)`` over the valid slots and
    every channel of each material (``nan`` when no slice has 3 samples)."""
    if xp is None:
        import jax.numpy as xp
    _, _, wl, wr, valid = nb
    r = residuals(z, nb, xp) / xp.sqrt(1.0 + wl**2 + wr**2)[..., None]
    r = xp.where(valid[..., None], xp.abs(r), np.nan)
    flat = r.reshape(*r.shape[:-3], -1)
    return _MAD_TO_SIGMA * xp.nanmedian(flat, axis=-1)


def weights(setting, z, t, count, nb=None, xp=None):
    """``β_s`` per material and slice ``(..., S)`` of a ``Config.slice_smoothing`` setting.

    Args:
        setting: a fixed ``β`` (float) or the rule ``(β_max, floor, scale)`` (module docstring).
        z: the values the slices interpolate ``(..., S, nmax, C)``.
        t, count: their slice parameters ``(..., S, nmax)`` and counts ``(..., S)``.
        nb: :func:`neighbours` of ``t`` and ``count`` when already computed.

    Returns:
        ``(β, σ̂)``: the weights and the noise level ``(...)`` (``nan`` for a fixed ``β``).
    """
    if xp is None:
        import jax.numpy as xp
    shape = z.shape[:-2]
    if not isinstance(setting, tuple):
        return xp.full(shape, setting, z.dtype), xp.full(shape[:-1], np.nan, z.dtype)
    beta_max, floor, scale = setting
    nb = neighbours(t, count, xp) if nb is None else nb
    sigma = noise_level(z, nb, xp)
    s2 = xp.where(xp.isfinite(sigma), sigma, 0.0)[..., None] ** 2
    spacing = 2.0 * np.pi / xp.maximum(xp.asarray(count), 1).astype(z.dtype)
    q = (spacing / SPACING_0) ** 2
    noise2 = xp.maximum(s2 - (floor * q) ** 2, 0.0)
    beta = beta_max * noise2 / (noise2 + (scale * q) ** 2)
    return beta.astype(z.dtype), sigma


def smooth(z, beta, nb, xp=None):
    """One shrink ``z ← z − β_s r`` with ``β`` per material and slice ``(..., S)``."""
    if xp is None:
        import jax.numpy as xp
    return z - xp.asarray(beta, z.dtype)[..., None, None] * residuals(z, nb, xp)


def smooth_slices(setting, z, t, count, xp=None):
    """``(smoothed z, β, σ̂)`` for a ``Config.slice_smoothing`` setting (``None``: unchanged,
    ``β`` and ``σ̂`` then ``None``)."""
    if setting is None:
        return z, None, None
    nb = neighbours(t, count, xp)
    beta, sigma = weights(setting, z, t, count, nb, xp)
    return smooth(z, beta, nb, xp), beta, sigma


def smooth_compact(setting, z, index, t, count, xp=None):
    """:func:`smooth_slices` of compact values ``z`` ``(B, n_in, C)`` (the valid samples in the
    order ``index`` of the flat ``(S · nmax)`` layout ``t`` ``(S, nmax)``, ``count`` ``(S,)``):
    the compiled operator's and the numpy operator entry's form. Returns the smoothed ``z``."""
    if xp is None:
        import jax.numpy as xp
    if setting is None:
        return z
    b, _, c = z.shape
    s, nmax = t.shape
    if xp is np:
        full = np.zeros((b, s * nmax, c), z.dtype)
        full[:, index, :] = z
    else:
        full = xp.zeros((b, s * nmax, c), z.dtype).at[:, index, :].set(z)
    full = smooth_slices(setting, full.reshape(b, s, nmax, c), t, count, xp)[0]
    return full.reshape(b, s * nmax, c)[:, index, :]


def smoothing_to_json(setting):
    """A ``Config.slice_smoothing`` as JSON: ``None``, a number or a list of three."""
    if setting is None:
        return None
    return [float(v) for v in setting] if isinstance(setting, tuple) else float(setting)


def smoothing_from_json(value):
    """Inverse of :func:`smoothing_to_json` (JSON has no tuples); validated by ``Config``."""
    return tuple(value) if isinstance(value, list) else value


def smoothing_report(setting, y, t, count, log_eps: float) -> dict | None:
    """What the smoothing does to one measurement (numpy; the model record's ``smoothing``):
    ``setting``, ``noise_log`` (``σ̂`` in the reconstruction's log values, or ``None`` for a fixed
    ``β``) and ``beta``: one weight per slice (0 for a slice of fewer than 3 samples). ``None``
    when ``setting`` is ``None``."""
    if setting is None:
        return None
    y, t, count = np.asarray(y, np.float64), np.asarray(t, np.float64), np.asarray(count)
    mask = np.arange(t.shape[-1])[None, :] < count[:, None]
    mean = np.abs(y[mask]).mean(axis=0) if mask.any() else np.zeros(y.shape[-1])
    eps = log_eps * mean + np.finfo(np.float32).tiny ** 0.5
    z = np.where(mask[..., None], np.log(np.maximum(y, 0.0) + eps), 0.0)
    nb = neighbours(t, count, np)
    beta, sigma = weights(setting, z, t, count, nb, np)
    beta = np.where(count >= 3, beta, 0.0)
    sigma = float(sigma)
    return {
        "setting": smoothing_to_json(setting),
        "noise_log": round(sigma, 6) if np.isfinite(sigma) else None,
        "beta": [round(float(b), 4) for b in beta],
    }


def slice_smoothing(meas, config) -> dict | None:
    """What ``config.slice_smoothing`` does to a grouped measurement: the noise it reads and
    the weight ``β`` of every slice (the model record's ``smoothing`` entry; numpy, no JAX).

    Args:
        meas: one grouped :class:`abrdf_jax.Measurements` (unbatched).
        config: the reconstruction's :class:`abrdf_jax.Config`.

    Returns:
        ``{"setting", "noise_log", "beta"}`` (``noise_log``: ``σ̂`` in the log samples the
        slices interpolate, ``None`` for a fixed weight; ``beta``: one per slice), or ``None``
        when the configuration does not smooth (setting ``None``, or a value space other than
        ``"logsamples"``).
    """
    from ._names import LOG_SAMPLES

    if config.value_space not in LOG_SAMPLES:
        return None
    return smoothing_report(config.slice_smoothing, meas.y, meas.t, meas.count, config.log_eps)
