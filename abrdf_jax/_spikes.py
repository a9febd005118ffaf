"""The spike cap: what the RBF sees of a specular peak that one sample caught.

A narrow peak (a mirror-like material's specular lobe) that one sample of a slice happens to
hit is a huge log value at one point. The slice interpolation turns it into a tent as wide as the
sample spacing (27.7° of φi − φv for 26 samples a slice), and the global RBF carries it across
elevations to pairs that never saw it. Whether a sample hits the peak is a lottery of the
sampling: 0.5° of encoder jitter turned ss440's ΔE76 from 5.4 into 30 (MERL test,
``python -m benchmarks.captures``, before this cap), and two extra elevation pairs through the
peak made chrome-steel 1.7x worse.

So, in the log-sample value space, the RBF is fitted to the subspaces restored from the log
samples capped at their quantile ``Config.spike_cap[0]`` (per material and channel, over the
valid samples; default :data:`SPIKE_QUANTILE`) plus the margin ``Config.spike_cap[1]``
(:data:`SPIKE_MARGIN`); the subspaces restored from the *uncapped* samples still go back at
their grid pairs, so a measured peak is kept where it was measured. Chosen on the MERL train
split by ``python -m benchmarks.spike_cap`` (``docs/captures.md``, "The spike cap"): the
lowest mean ΔE76 over five capture kinds (protocol, 100 per slice, 0.5° jitter, 5 % noise, two
extra pairs). It is elementwise in the samples, so the compiled operator applies it too: the
map stays ``M · cap(z)`` but at the kept rows, where the uncapped ``M[keep] · z`` goes (``_operator.py``).
"""

import numpy as np

#: Quantile of a material's valid log samples (per channel) and margin above it (log units,
#: x 1.65) where the RBF's input is capped.
SPIKE_QUANTILE, SPIKE_MARGIN = 0.93, 0.5


def cap_samples(z, cap=(SPIKE_QUANTILE, SPIKE_MARGIN), mask=None, xp=None):
    """``min(z, quantile(z, q) + margin)`` per material and channel, ``cap = (q, margin)``.

    Args:
        z: log sample values, ``(..., S, nmax, C)`` with ``mask`` ``(..., S, nmax)`` marking the
            valid ones, or compact ``(..., n, C)`` (every entry valid) without a mask.
        xp: ``jax.numpy`` (default) or ``numpy`` (the JAX-free operator entry).
    """
    q, margin = cap
    if xp is None:
        import jax.numpy as xp

        if mask is None:
            return xp.minimum(z, upper_quantile(z, q) + margin)
    if mask is None:
        return xp.minimum(z, xp.quantile(z, q, axis=-2, keepdims=True) + margin)
    flat = xp.where(mask[..., None], z, np.nan).reshape(*z.shape[:-3], -1, z.shape[-1])
    level = xp.nanquantile(flat, q, axis=-2)[..., None, None, :]
    return xp.minimum(z, level + margin)


#: Most passes :func:`upper_quantile` makes before it sorts instead.
SELECT_PASSES = 24


def upper_quantile(z, q: float):
    """``jnp.quantile(z, q, axis=-2, keepdims=True)`` (linear) from the largest values of ``z``.

    The quantile needs two order statistics; for ``q`` near 1 they are among the few largest
    values, found by that many passes of max-and-remove. XLA's CPU sort is a comparator call
    per comparison: the sort took a quarter of the capped operator's time at 1,000 materials
    (``python -m benchmarks.throughput``). The weights are computed as ``jnp.quantile``
    computes them, in ``z``'s dtype; above :data:`SELECT_PASSES` passes it sorts.
    """
    import jax
    import jax.numpy as jnp

    n = z.shape[-2]
    dtype = np.dtype(z.dtype)
    h = dtype.type(q) * dtype.type(n - 1)  # the same rounding as jnp.quantile's
    low = int(np.floor(h))
    passes = n - low
    if passes > SELECT_PASSES or not np.issubdtype(dtype, np.floating):
        return jnp.quantile(z, q, axis=-2, keepdims=True)
    w = h - dtype.type(low)
    cur = jnp.swapaxes(z, -1, -2)  # reduce along the contiguous axis
    # Pass j takes the largest value left and removes every copy of it (ties counted), so the
    # value at descending rank d is the one whose copies cover d.
    d_lo, d_hi = n - 1 - low, n - 1 - min(low + 1, n - 1)
    nan = jnp.any(jnp.isnan(cur), axis=-1)  # NaN anywhere: NaN, as jnp.quantile

    def take(_, state):
        cur, lo, hi, seen = state
        m = jnp.max(cur, axis=-1)
        hit = cur == m[..., None]
        after = seen + jnp.sum(hit, axis=-1, dtype=np.int32)
        lo = jnp.where((seen <= d_lo) & (d_lo < after), m, lo)
        hi = jnp.where((seen <= d_hi) & (d_hi < after), m, hi)
        return jnp.where(hit, -jnp.inf, cur), lo, hi, after

    # a loop, not unrolled passes: XLA would fuse the producers of ``z`` into every pass
    none = jnp.full(cur.shape[:-1], -jnp.inf, cur.dtype)
    start = (cur, none, none, jnp.zeros(cur.shape[:-1], np.int32))
    _, lo, hi, _ = jax.lax.fori_loop(0, passes, take, start)
    level = jnp.where(nan, jnp.nan, lo * (dtype.type(1) - w) + hi * w)
    return level[..., None, :]
