"""The spike cap: what the RBF sees of a specular peak that one sample caught.

A narrow peak (a mirror-like material's specular lobe) that one sample of a slice happens to
hit is a huge log value at one point. The slice interpolation turns it into a tent as wide as the
sample spacing (27.7° of φi − φv for 26 samples a slice), and the global RBF carries it across
elevations to pairs that never saw it. Whether a sample hits the peak is a lottery of the
sampling: 0.5° of encoder jitter turned ss440's ΔE76 from 5.4 into 30 (MERL test,
``python -m benchmarks.captures``, before this cap), and two extra elevation pairs through the
peak made chrome-steel 1.7x worse.

So, in the log-sample value space, the RBF is fitted to the subspaces restored from the log
samples capped at their :data:`SPIKE_QUANTILE` (per material and channel, over the valid samples)
plus :data:`SPIKE_MARGIN`; the subspaces restored from the *uncapped* samples still go back at
their grid pairs, so a measured peak is kept where it was measured. Chosen on the MERL train
split (``docs/captures.md``, "The spike cap"): among quantiles 0.8–0.97 and margins 0.25–0.5, the
lowest mean ΔE76 over five capture kinds (protocol, 100 per slice, 0.5° jitter, 5 % noise, two
extra pairs). It is elementwise in the samples, so the compiled operator applies it too: the
map stays ``M · cap(z)`` plus the uncapped correction at the kept rows (``_operator.py``).
"""

import numpy as np

#: Quantile of a material's valid log samples (per channel) and margin above it (log units,
#: x 1.65) where the RBF's input is capped.
SPIKE_QUANTILE, SPIKE_MARGIN = 0.93, 0.5


def cap_samples(z, mask=None, xp=None):
    """``min(z, quantile(z, SPIKE_QUANTILE) + SPIKE_MARGIN)`` per material and channel.

    Args:
        z: log sample values, ``(..., S, nmax, C)`` with ``mask`` ``(..., S, nmax)`` marking the
            valid ones, or compact ``(..., n, C)`` (every entry valid) without a mask.
        xp: ``jax.numpy`` (default) or ``numpy`` (the JAX-free operator entry).
    """
    if xp is None:
        import jax.numpy as xp
    if mask is None:
        cap = xp.quantile(z, SPIKE_QUANTILE, axis=-2, keepdims=True)
        return xp.minimum(z, cap + SPIKE_MARGIN)
    flat = xp.where(mask[..., None], z, np.nan).reshape(*z.shape[:-3], -1, z.shape[-1])
    cap = xp.nanquantile(flat, SPIKE_QUANTILE, axis=-2)[..., None, None, :]
    return xp.minimum(z, cap + SPIKE_MARGIN)
