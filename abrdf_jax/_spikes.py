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
map stays ``M · cap(z)`` plus the uncapped correction at the kept rows (``_operator.py``).
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
    if xp is None:
        import jax.numpy as xp
    q, margin = cap
    if mask is None:
        return xp.minimum(z, xp.quantile(z, q, axis=-2, keepdims=True) + margin)
    flat = xp.where(mask[..., None], z, np.nan).reshape(*z.shape[:-3], -1, z.shape[-1])
    level = xp.nanquantile(flat, q, axis=-2)[..., None, None, :]
    return xp.minimum(z, level + margin)
