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

import functools

import numpy as np

from ._host_eps import sample_eps
from ._memo import BoundedMemo
from ._per_layout import layout_of, per_layout, stacked_values

#: The spacing ``Δ_0`` (radians) at which the rule's ``floor`` and ``scale`` are given: the
#: protocol's diagonal slices (26 samples).
SPACING_0 = 2.0 * np.pi / 26
_MAD_TO_SIGMA = 1.4826
_TWO_PI = 2.0 * np.pi


def neighbours(t, count, xp=None):
    """``(left, right, wl, wr, valid, slice_of)`` of every slot of one padded slice layout.

    Args:
        t: slice parameters ``(S, nmax)`` (radians, sorted within each slice).
        count: valid samples per slice ``(S,)``.

    Returns:
        Six arrays over the flat slots ``s · nmax + k`` (``(S · nmax,)`` each): the flat index of
        each slot's left and right neighbour (periodic within the first ``count`` slots of its
        slice), their interpolation weights, ``valid`` (the slot is a sample of a slice with at
        least 3 samples: only those are smoothed and enter ``σ̂``) and the slot's slice.
    """
    if xp is None:
        import jax.numpy as xp
    if xp is np:  # on the host: one build per layout (a folder's files share their angles)
        t, count = np.ascontiguousarray(t), np.ascontiguousarray(count)
        key = (t.shape, t.dtype.str, t.tobytes(), count.dtype.str, count.tobytes())
        return _HOST_NEIGHBOURS.get(key, lambda: _frozen(_neighbours(t, count, np)))
    return _neighbours(t, count, xp)


def _frozen(arrays):
    for a in arrays:
        a.flags.writeable = False  # shared by every caller of the memo
    return arrays


def _neighbours(t, count, xp):
    s, nmax = t.shape
    n = xp.asarray(count)[:, None]
    k = xp.arange(nmax, dtype=n.dtype)[None, :]  # one integer type and rank (strict promotion)
    n1 = xp.maximum(n, 1)
    left = (k - 1) % n1
    right = (k + 1) % n1
    tl = xp.take_along_axis(t, left, axis=-1) - xp.where(k == 0, _TWO_PI, 0.0)
    tr = xp.take_along_axis(t, right, axis=-1) + xp.where(k == n - 1, _TWO_PI, 0.0)
    span = tr - tl
    ok = span > 0
    wr = xp.where(ok, (t - tl) / xp.where(ok, span, 1.0), 0.5).astype(t.dtype)
    valid = (k < n) & (n >= 3)
    slices = xp.arange(s, dtype=n.dtype)[:, None]
    base = slices * nmax
    slice_of = xp.broadcast_to(slices, (s, nmax))
    parts = (left + base, right + base, 1.0 - wr, wr, valid, slice_of)
    return tuple(a.reshape(-1) for a in parts)


_HOST_NEIGHBOURS = BoundedMemo(256)


def compact(nb, index, xp=None):
    """:func:`neighbours` restricted to the slots ``index`` ``(n,)`` (the valid samples, the
    compiled operator's input order), neighbour indices into that order."""
    if xp is None:
        import jax.numpy as xp
    left, right, wl, wr, valid, slice_of = nb
    n = index.shape[0]
    if xp is np:
        inv = np.zeros(left.shape[0], np.int64)
        inv[index] = np.arange(n)
    else:
        inv = xp.zeros(left.shape[0], xp.int32).at[index].set(xp.arange(n, dtype=xp.int32))
    return inv[left[index]], inv[right[index]], wl[index], wr[index], valid[index], slice_of[index]


def residuals(z, nb, xp=None):
    """``r_k = z_k − (w_l z_{k−1} + w_r z_{k+1})`` of values ``z`` ``(..., n, C)`` on the slots of
    ``nb`` (0 at slots that are not ``valid``)."""
    if xp is None:
        import jax.numpy as xp
    left, right, wl, wr, valid, _ = nb
    r = z - (_column(wl, z) * z[..., left, :] + _column(wr, z) * z[..., right, :])
    return xp.where(_column(valid, z), r, 0.0)


def _column(a, z):
    """Per-slot ``a`` ``(n,)`` shaped to broadcast against values ``z`` ``(..., n, C)`` (explicit
    ranks: no implicit rank promotion)."""
    return a.reshape(*(1,) * (z.ndim - 2), a.shape[0], 1)


def noise_level(z, nb, xp=None, r=None):
    """``σ̂`` ``(...)``: ``1.4826 · median |r| / sqrt(1 + w_l² + w_r²)`` over the valid slots and
    every channel of values ``z`` ``(..., n, C)`` (``nan`` when no slice has 3 samples);
    ``r``: :func:`residuals` of ``z`` when the caller has them."""
    if xp is None:
        import jax.numpy as xp
    _, _, wl, wr, valid, _ = nb
    r = residuals(z, nb, xp) if r is None else r
    r = r / _column(xp.sqrt(1.0 + wl**2 + wr**2), z)
    r = xp.where(_column(valid, z), xp.abs(r), np.nan)
    flat = r.reshape(*r.shape[:-2], -1)
    if xp is np:  # numpy's nanmedian goes through masked arrays: ~1 ms a material on the host
        cols = np.flatnonzero(~np.isnan(flat.reshape(-1, flat.shape[-1])).any(axis=0))
        if not cols.size:
            return np.full(flat.shape[:-1], np.nan, flat.dtype)
        return _MAD_TO_SIGMA * np.median(flat[..., cols], axis=-1)
    return _MAD_TO_SIGMA * nonneg_nanmedian(flat)


def nonneg_nanmedian(a):
    """``jnp.nanmedian(a, axis=-1)`` of values ``a`` that are ``≥ 0`` or NaN, without a sort.

    XLA's CPU sort calls a comparator per comparison: the median of 1,000 materials' residuals
    took a quarter of the smoothed operator's time (``python -m benchmarks.throughput``). For
    non-negative floats the bit pattern read as an integer is monotone in the value, so the
    lower middle order statistic is found by bisection on it (one counting pass per bit, 31 for
    float32, in a loop); the upper one (the next rank, for even counts) is then the same value
    when it has copies enough, else the smallest value above it: two passes more, not a second
    bisection. The values are the bit patterns found, averaged as ``jnp.nanmedian`` does; the
    derivative (a ``custom_jvp``: nothing of it runs where nothing is differentiated) goes to
    the elements they are. On the BTF chunk map (1,024 texels, 210 samples) the smoothing went
    from 32 to 8 ms with the bisection.
    """
    return _nanmedian()(a)


def _order_statistics(a):
    """``(median, bits, lo, hi, ok, n)`` of :func:`nonneg_nanmedian`: the bit patterns (NaN slots
    at the integer maximum), those of the two middle order statistics, the valid slots and their
    count per row."""
    import jax
    import jax.numpy as jnp

    ints = {2: jnp.int16, 4: jnp.int32, 8: jnp.int64}[a.dtype.itemsize]
    top = jnp.iinfo(ints).max
    ok = ~jnp.isnan(a)
    # NaN slots above every value (no bisection point reaches ``top``). The barrier materialises
    # the bit patterns once: the loop and everything after it read these, where XLA would
    # otherwise fuse the producers of ``a`` (the residuals' gathers) into every counting pass,
    # and a fusion that recomputes ``a`` may round it differently (seen at XLA's optimisation
    # level 0). Plain halvings in the loop, the upper rank after it (no conditional in the loop).
    bits = jax.lax.bitcast_convert_type(jnp.where(ok, a, 0), ints)
    bits = jax.lax.optimization_barrier(jnp.where(ok, bits, top))
    n = jnp.sum(ok, axis=-1)
    k_lo = (jnp.maximum(n, 1) - 1) // 2  # the two middle ranks (equal for odd n), from 0
    k_hi = jnp.maximum(n, 1) // 2

    def halve(_, bounds):  # towards the smallest b with more than k_lo bits <= b
        lo, hi = bounds
        mid = lo + (hi - lo) // 2
        more = jnp.sum(bits <= mid[..., None], axis=-1) > k_lo
        return jnp.where(more, lo, mid + 1), jnp.where(more, mid, hi)

    start = (jnp.zeros(n.shape, ints), jnp.full(n.shape, top, ints))
    lo, _ = jax.lax.fori_loop(0, 8 * a.dtype.itemsize - 1, halve, start)
    # rank k_hi: lo itself if it has copies enough, else the next value
    at_most = jnp.sum(bits <= lo[..., None], axis=-1)
    above = jnp.min(jnp.where(bits > lo[..., None], bits, top), axis=-1)
    hi = jnp.where(at_most > k_hi, lo, above)
    low, high = (jax.lax.bitcast_convert_type(v, a.dtype) for v in (lo, hi))
    med = jnp.where(n > 0, low * 0.5 + high * 0.5, jnp.nan).astype(a.dtype)
    return med, bits, lo, hi, ok, n


def _median_jvp(primals, tangents):
    """Half of the mean tangent of the elements at each of the two middle order statistics."""
    import jax.numpy as jnp

    (a,), (da,) = primals, tangents
    med, bits, lo, hi, ok, n = _order_statistics(a)
    dmed = jnp.zeros(med.shape, a.dtype)
    for v in (lo, hi):
        pick = ok & (bits == v[..., None])
        moved = jnp.sum(jnp.where(pick, da, 0.0), axis=-1)
        dmed = dmed + 0.5 * moved / jnp.maximum(jnp.sum(pick, axis=-1), 1).astype(a.dtype)
    return med, jnp.where(n > 0, dmed, 0.0).astype(a.dtype)


@functools.cache
def _nanmedian():
    """:func:`nonneg_nanmedian` as a ``jax.custom_jvp`` (made on first use: this module imports no
    JAX at import, for the numpy operator entry)."""
    import jax

    f = jax.custom_jvp(lambda a: _order_statistics(a)[0])
    f.defjvp(_median_jvp)
    return f


def weights(setting, z, count, nb, xp=None, r=None):
    """``β_s`` per material and slice ``(..., S)`` of a ``Config.slice_smoothing`` setting.

    Args:
        setting: a fixed ``β`` (float) or the rule ``(β_max, floor, scale)`` (module docstring).
        z: the values the slices interpolate, ``(..., n, C)`` on the slots of ``nb``.
        count: samples per slice ``(S,)``.
        nb: :func:`neighbours` (or :func:`compact`) of the layout.
        r: :func:`residuals` of ``z``, when the caller has them.

    Returns:
        ``(β, σ̂)``: the weights and the noise level ``(...)`` (``nan`` for a fixed ``β``).
    """
    if xp is None:
        import jax.numpy as xp
    lead = z.shape[:-2]
    if not isinstance(setting, tuple):
        beta = xp.full((*lead, count.shape[0]), setting, z.dtype)
        return beta, xp.full(lead, np.nan, z.dtype)
    beta_max, floor, scale = setting
    sigma = noise_level(z, nb, xp, r)
    s2 = xp.where(xp.isfinite(sigma), sigma, 0.0)[..., None] ** 2
    spacing = 2.0 * np.pi / xp.maximum(xp.asarray(count), 1).astype(z.dtype)
    q = ((spacing / SPACING_0) ** 2).reshape(*(1,) * len(lead), -1)
    noise2 = xp.maximum(s2 - (floor * q) ** 2, 0.0)
    beta = beta_max * noise2 / (noise2 + (scale * q) ** 2)
    return beta.astype(z.dtype), sigma


def smooth(z, beta, nb, xp=None, r=None):
    """One shrink ``z ← z − β_s r`` of ``z`` ``(..., n, C)``, ``β`` per slice ``(..., S)``
    (``r``: :func:`residuals` of ``z``, when the caller has them)."""
    if xp is None:
        import jax.numpy as xp
    b = xp.asarray(beta, z.dtype)[..., nb[5]]  # each slot's slice
    return z - b[..., None] * (residuals(z, nb, xp) if r is None else r)


def smooth_slices(setting, z, t, count, xp=None):
    """``(smoothed z, β, σ̂)`` of padded values ``z`` ``(..., S, nmax, C)`` (one layout ``t``
    ``(S, nmax)``, ``count`` ``(S,)``) for a ``Config.slice_smoothing`` setting (``None``:
    unchanged, ``β`` and ``σ̂`` then ``None``)."""
    if setting is None:
        return z, None, None
    nb = neighbours(t, count, xp)
    flat = z.reshape(*z.shape[:-3], -1, z.shape[-1])
    r = residuals(flat, nb, xp)  # once, for the noise estimate and the shrink
    beta, sigma = weights(setting, flat, count, nb, xp, r)
    return smooth(flat, beta, nb, xp, r).reshape(z.shape), beta, sigma


def smooth_compact(setting, z, index, t, count, xp=None, nb=None):
    """The smoothing of compact values ``z`` ``(B, n_in, C)`` (the valid samples in the order
    ``index`` of the flat ``(S · nmax)`` layout ``t`` ``(S, nmax)``, ``count`` ``(S,)``): the
    compiled operator's and the numpy operator entry's form, without the padded layout.
    ``nb``: :func:`compact` neighbours of the layout when the caller holds them
    (:func:`operator_neighbours`)."""
    if setting is None:
        return z
    nb = compact(neighbours(t, count, xp), index, xp) if nb is None else nb
    r = residuals(z, nb, xp)  # once, for the noise estimate and the shrink
    return smooth(z, weights(setting, z, count, nb, xp, r)[0], nb, xp, r)


def smooths_slices(config) -> bool:
    """Whether ``config`` smooths its slices: a ``slice_smoothing`` setting with the log taken
    of the samples (``value_space="logsamples"``), the one value space it runs in (the
    pipeline's ``smoothed_samples``, the compiled operator's and the numpy entry's apply)."""
    from ._names import LOG_SAMPLES

    return config.slice_smoothing is not None and config.value_space in LOG_SAMPLES


def operator_neighbours(config, built, dtype):
    """The :func:`compact` neighbours of the valid samples of a compiled operator (``config``
    and its ``_operator.BuiltMatrix`` ``built``), computed once on the host as the numpy operator
    entry computes them, as JAX arrays (``left``, ``right``, ``slice_of`` int32; ``wl``, ``wr``
    in ``dtype``): the operator keeps them, so its apply searches no neighbours (the search was
    a quarter of the BTF chunk map's compilation; docs/notes.md). ``None`` where the operator
    does not smooth (no setting, not single stage, not log samples) or its layout is traced."""
    import jax
    import jax.numpy as jnp

    t, count, index = built.t, built.count, built.index
    if (
        not smooths_slices(config)
        or built.stage != "single"
        or any(isinstance(a, jax.core.Tracer) for a in (t, count, index))
    ):
        return None
    t, count = np.asarray(t, dtype), np.asarray(count)
    left, right, wl, wr, valid, slice_of = compact(neighbours(t, count, np), np.asarray(index), np)
    left, right, slice_of = (jnp.asarray(a, jnp.int32) for a in (left, right, slice_of))
    wl, wr, valid = jnp.asarray(wl, dtype), jnp.asarray(wr, dtype), jnp.asarray(valid, bool)
    return left, right, wl, wr, valid, slice_of


def smoothing_to_json(setting):
    """A ``Config.slice_smoothing`` as JSON: ``None``, a number or a list of three."""
    if setting is None:
        return None
    return [float(v) for v in setting] if isinstance(setting, tuple) else float(setting)


def smoothing_from_json(value):
    """Inverse of :func:`smoothing_to_json` (JSON has no tuples); validated by ``Config``."""
    return tuple(value) if isinstance(value, list) else value


def smoothing_reports(setting, y, t, count, log_eps: float) -> list:
    """What the smoothing does to each of the measurements ``y`` ``(B, S, nmax, C)`` of one
    layout (``t``, ``count``), in one vectorised pass (numpy; the model record's ``smoothing``):
    ``setting``, ``noise_log`` (``σ̂`` in the reconstruction's log values, or ``None`` for a fixed
    ``β``) and ``beta``: one weight per slice (0 for a slice of fewer than 3 samples). ``None``
    for each when ``setting`` is ``None``."""
    if setting is None:
        return [None] * len(y)
    y, t, count = np.asarray(y, np.float64), np.asarray(t, np.float64), np.asarray(count)
    mask = np.arange(t.shape[-1])[None, :] < count[:, None]
    x = y[:, mask] if mask.any() else np.zeros((len(y), 1, y.shape[-1]))
    eps = sample_eps(x, log_eps, axis=1)  # (B, C)
    z = np.where(mask[..., None], np.log(np.maximum(y, 0.0) + eps[:, None, None, :]), 0.0)
    nb = neighbours(t, count, np)
    beta, sigma = weights(setting, z.reshape(len(y), -1, z.shape[-1]), count, nb, np)
    beta = np.where(count >= 3, beta, 0.0)
    return [
        {
            "setting": smoothing_to_json(setting),
            "noise_log": round(float(s), 6) if np.isfinite(s) else None,
            "beta": [round(float(v), 4) for v in b],
        }
        for b, s in zip(beta, np.reshape(sigma, -1))
    ]


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
    return slice_smoothings([meas], [config])[0]


def slice_smoothings(measurements, configs) -> list:
    """:func:`slice_smoothing` of every ``(measurement, config)`` pair; those that share a
    layout and a setting in one vectorised pass (:func:`smoothing_reports`: the same numbers)."""

    def key(m, c):
        if smooths_slices(c):
            return (repr(c.slice_smoothing), float(c.log_eps), *layout_of(m))
        return None

    def run(ks):
        m, c = measurements[ks[0]], configs[ks[0]]
        y = stacked_values(measurements, ks)
        return smoothing_reports(c.slice_smoothing, y, m.t, m.count, c.log_eps)

    return per_layout([key(m, c) for m, c in zip(measurements, configs)], run)
