"""A noise-aware isotropy test from the axial slices (Filip 2012, eq. 1 and 5).

On an axial slice the sample rotates under fixed light and camera: ``φi − φv = α`` stays fixed,
so an isotropic material (whose ABRDF depends on the azimuths only through ``φi − φv``) gives a
*constant* axial slice, and the diagonal slices alone then determine every toroidal subspace
(eq. 5). Measured slices are never exactly constant (noise), and synthetic ones are constant
only up to rounding, so the test compares the axial slices' variation with a noise level:

1. Values are compared in log space, ``l = ln(Y + ε)`` with ``Y`` the luminance (PROTOCOL.md's
   weights) and ``ε = 10⁻⁴ · mean Y`` (a guard against zeros): multiplicative (relative) noise,
   the model assumed here, becomes additive with one standard deviation ``σ`` for every sample
   (for ``Y ≫ ε``), and the result does not depend on the exposure.
2. The noise level ``σ`` is given by the user (relative noise of a sample) or estimated from the
   data: the residual of every axial sample against the linear interpolation of its two
   neighbours, normalised so that independent noise of standard deviation ``σ`` gives residuals
   of standard deviation ``σ``, and summarised robustly as ``1.4826 · median |residual|`` (the
   normal-consistent MAD; Donoho & Johnstone, Biometrika 81(3), 1994 use the same estimator on
   the finest wavelet coefficients). Under isotropy the axial slice is constant, so the residual
   is pure noise and the test is calibrated; an anisotropic axial slice varies smoothly (with
   the 180° period of the tangent frame), so its residual is still mostly noise, and a sharp
   feature can only inflate the estimate (a conservative test, never an anti-conservative one).
   The diagonal slices are no good for this: their highlights and grazing-angle curvature
   (MERL materials) would set the "noise" several times too high.
3. Under isotropy and independent Gaussian noise, ``Q = Σ_p Σ_k (l_pk − l̄_p)² / σ²`` over the
   axial samples ``k`` of every measured pair ``p`` is χ² with ``Σ_p (n_p − 1)`` degrees of
   freedom (the mean of each slice is estimated). The report gives ``Q / dof`` (≈ 1 for pure
   noise) and the p-value ``P(χ² ≥ Q)``.
4. A statistically significant variation can still be too small to matter (noise-free data make
   any anisotropy significant). The effect size is the RMS variation of the axial slices in log
   units — the relative error that predicting them as constant (eq. 5) makes, less the noise's
   expected share — and the material
   counts as anisotropic only when the p-value is below ``level`` *and* the effect is at least
   ``min_effect``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._errors import InputError
from ..metrics._metrics import LUMA_WEIGHTS
from .._measurements import Samples
from .._measurements import Measurements, group_slices

#: Default significance level and minimum effect (RMS log variation of the axial slices).
LEVEL = 1e-3
MIN_EFFECT = 0.02
#: ε of the test's log transform, relative to the mean luminance: small, so that multiplicative
#: noise keeps one standard deviation in log space down to samples 1000x darker than the mean
#: (the pipeline's 1 % would damp the noise of dark samples and unbalance the pooled estimate).
LOG_EPS = 1e-4
_MAD_TO_SIGMA = 1.4826


@dataclasses.dataclass(frozen=True)
class IsotropyReport:
    """Outcome of :func:`isotropy_test`.

    Attributes:
        isotropic: the decision (``True`` when no axial slice was measured: nothing contradicts
            isotropy, and the diagonal-only model is the only one the data allow).
        measured: whether any axial slice was measured (otherwise the test could not run).
        statistic: ``Q / dof``, the axial slices' variance in units of the noise variance
            (≈ 1 for an isotropic material with independent noise; ``nan`` if not measured).
        p_value: ``P(χ²_dof ≥ Q)`` under isotropy (``nan`` if not measured).
        dof: degrees of freedom ``Σ (n_p − 1)``.
        effect: RMS variation of the axial slices about their means, log units (a relative
            error: 0.05 ≈ 5 %), pooled over the pairs, with the noise's expected share removed
            (``sqrt(max(Σr² − dof·σ², 0) / n)``).
        noise: the noise standard deviation ``σ`` used, log units.
        noise_source: ``"given"`` or ``"estimated"`` (see the module docstring).
        level, min_effect: the thresholds of the decision.
        per_pair: one dict per measured pair: ``pair``, ``n``, ``effect``, ``statistic``.
        reason: one sentence explaining the decision.
    """

    isotropic: bool
    measured: bool
    statistic: float
    p_value: float
    dof: int
    effect: float
    noise: float
    noise_source: str
    level: float
    min_effect: float
    per_pair: tuple = ()
    reason: str = ""

    def to_dict(self) -> dict:
        """JSON-ready dictionary (non-finite numbers as ``None``)."""
        out = dataclasses.asdict(self)
        for k, v in out.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
        out["per_pair"] = [dict(d, pair=list(d["pair"])) for d in self.per_pair]
        return out


def chi2_sf(q: float, dof: int) -> float:
    """Survival function ``P(χ²_dof ≥ q)`` in float64 (no SciPy needed).

    The regularised upper incomplete gamma ``Q(dof/2, q/2)``: its power series below
    ``x = a + 1`` and Lentz's continued fraction above (Numerical Recipes, 3rd ed., §6.2).
    """
    if dof <= 0 or not math.isfinite(q):
        return float("nan") if dof <= 0 or math.isnan(q) else 0.0
    a, x = dof / 2.0, max(q, 0.0) / 2.0
    if x == 0.0:
        return 1.0
    log_front = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1.0:  # P(a, x) by its series; Q = 1 - P
        term = total = 1.0 / a
        ap = a
        for _ in range(10_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-16:
                break
        return max(0.0, 1.0 - total * math.exp(log_front))
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return min(1.0, math.exp(log_front) * h)


def _log_luminance(meas: Measurements, log_eps: float):
    y = np.asarray(meas.y, np.float64)
    cnt = np.asarray(meas.count)
    lum = y @ np.asarray(LUMA_WEIGHTS, np.float64)  # (S, nmax)
    valid = np.arange(y.shape[1])[None, :] < cnt[:, None]
    mean = np.abs(lum[valid]).mean() if valid.any() else 0.0
    eps = log_eps * mean + np.finfo(np.float64).tiny ** 0.5
    return np.log(np.maximum(lum, 0.0) + eps), cnt


def _interp_weights(t: np.ndarray) -> np.ndarray:
    """Weight ``wr`` of the right neighbour when each sample of a periodic slice (parameters
    ``t``, sorted) is linearly interpolated from its two neighbours (``wl = 1 − wr``)."""
    tl = np.roll(t, 1).copy()
    tl[0] -= 2 * np.pi
    tr = np.roll(t, -1).copy()
    tr[-1] += 2 * np.pi
    span = np.where(tr - tl > 0, tr - tl, 1.0)
    return (t - tl) / span


def _interp_residuals(t: np.ndarray, l: np.ndarray) -> np.ndarray:
    """Residual of each sample of a periodic slice against its neighbours' linear interpolation.

    Normalised to unit variance for unit independent noise: ``r / sqrt(1 + wl² + wr²)``.
    """
    if len(t) < 3:
        return np.zeros(0)
    wr = _interp_weights(t)
    wl = 1.0 - wr
    r = l - (wl * np.roll(l, 1) + wr * np.roll(l, -1))
    return r / np.sqrt(1.0 + wl**2 + wr**2)


def estimate_noise(meas: Measurements, log_eps: float = None, slices: str = "axial") -> float:
    """Robust noise level (log units) from the slices' high-frequency residuals.

    Args:
        meas: the grouped measurement.
        log_eps: ``ε`` of the log transform, relative to the mean luminance.
        slices: ``"axial"`` (default; the diagonal slices when no axial slice was measured),
            ``"diagonal"`` or ``"all"``: which slices' residuals enter the median.

    Returns:
        ``σ`` in log units (``nan`` when no slice has 3 samples).
    """
    log_eps = LOG_EPS if log_eps is None else log_eps
    if slices not in ("axial", "diagonal", "all"):
        raise InputError(f"slices must be 'axial', 'diagonal' or 'all', got {slices!r}")
    l, cnt = _log_luminance(meas, log_eps)
    t = np.asarray(meas.t, np.float64)
    if slices == "axial" and not np.any(cnt[0::2] >= 3):
        slices = "diagonal"
    rows = {"axial": range(0, len(cnt), 2), "diagonal": range(1, len(cnt), 2), "all": range(len(cnt))}[slices]
    res = [_interp_residuals(t[s, : cnt[s]], l[s, : cnt[s]]) for s in rows]
    res = np.concatenate(res) if res else np.zeros(0)
    if res.size == 0:
        return float("nan")
    return float(_MAD_TO_SIGMA * np.median(np.abs(res)))


def isotropy_test(
    samples: Samples | Measurements,
    *,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    alpha_deg: float | None = None,
    log_eps: float = LOG_EPS,
) -> IsotropyReport:
    """Decide from the axial slices whether a material is isotropic (module docstring).

    Args:
        samples: measured samples (grouped here, α estimated unless ``alpha_deg``) or grouped
            :class:`Measurements`.
        noise: relative noise of one sample (e.g. 0.03 for 3 %), if known; default: estimated
            from the diagonal slices.
        level: significance level of the χ² test.
        min_effect: smallest RMS variation (log units) of the axial slices that counts as
            anisotropy worth modelling.
        alpha_deg: slice offset for grouping :class:`Samples`.
        log_eps: ``ε`` of the log transform, relative to the mean luminance (:data:`LOG_EPS`).

    Returns:
        An :class:`IsotropyReport`.

    Raises:
        InputError: on a negative ``noise``, a ``level`` outside (0, 1) or a negative ``min_effect``.
    """
    if noise is not None and not (math.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a finite relative level >= 0, got {noise!r}")
    if not 0 < level < 1:
        raise InputError(f"level must lie in (0, 1), got {level!r}")
    if not min_effect >= 0:
        raise InputError(f"min_effect must be >= 0, got {min_effect!r}")
    if isinstance(samples, Samples):
        samples, _ = group_slices(samples, alpha_deg, dtype=np.float64)
    elif not isinstance(samples, Measurements):
        raise InputError(f"samples must be Samples or Measurements, got {type(samples).__name__}")
    meas = samples
    l, cnt = _log_luminance(meas, log_eps)
    floor = 1e-6  # log units: float32 rounding of constant slices stays below it
    if noise is None:
        sigma, source = estimate_noise(meas, log_eps), "estimated"
    else:
        sigma, source = float(noise), "given"
    sigma = max(sigma, floor) if math.isfinite(sigma) else floor
    per_pair, q, dof, ss, nn = [], 0.0, 0, 0.0, 0
    for p, pair in enumerate(meas.pairs):
        n = int(cnt[2 * p])
        if n < 3:
            continue
        r = l[2 * p, :n] - l[2 * p, :n].mean()
        qp = float(np.sum(r**2) / sigma**2)
        eff = float(np.sqrt(max(float(np.sum(r**2)) - (n - 1) * sigma**2, 0.0) / n))
        per_pair.append(dict(pair=tuple(pair), n=n, effect=eff, statistic=qp / (n - 1)))
        q, dof, ss, nn = q + qp, dof + n - 1, ss + float(np.sum(r**2)), nn + n
    common = dict(noise=sigma, noise_source=source, level=level, min_effect=min_effect)
    if not per_pair:
        return IsotropyReport(
            isotropic=True, measured=False, statistic=float("nan"), p_value=float("nan"), dof=0,
            effect=float("nan"), per_pair=(), **common,
            reason="no axial slice was measured: only the diagonal-only model (eq. 5) is possible",
        )
    # The raw RMS includes the noise: remove its expected share (n_p - 1) σ² per pair.
    effect = math.sqrt(max(ss - dof * sigma**2, 0.0) / nn)
    stat = q / dof
    pval = chi2_sf(q, dof)
    significant = pval < level
    material = effect >= min_effect
    iso = not (significant and material)
    if iso and not significant:
        why = (f"the axial slices vary no more than the noise (chi2/dof {stat:.3g}, p = {pval:.3g} >= {level:g}, "
               f"noise {sigma:.3g} {source})")
    elif iso:
        why = (f"the axial slices vary significantly (p = {pval:.3g}) but only by {effect:.3g} RMS in log units "
               f"(< {min_effect:g}): too little to model")
    else:
        why = (f"the axial slices vary by {effect:.3g} RMS in log units, {stat:.3g}x the noise variance "
               f"(p = {pval:.3g} < {level:g}, noise {sigma:.3g} {source})")
    return IsotropyReport(
        isotropic=iso, measured=True, statistic=stat, p_value=pval, dof=dof, effect=effect,
        per_pair=tuple(per_pair), reason=("isotropic: " if iso else "anisotropic: ") + why, **common,
    )


# ------------------------------------------------------------------------------------------------
# The same test for many materials of one sample geometry (every texel of a BTF), in JAX


def isotropy_batch(
    y,
    t,
    count,
    *,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    log_eps: float = LOG_EPS,
):
    """:func:`isotropy_test` for a batch of materials measured with one slice layout.

    The slice layout (``t``, ``count``) is shared, so the test is a fixed sequence of gathers and
    reductions: jit-able, vmapped over the leading axis of ``y``, and cheap beside a
    reconstruction (``O(n)`` per material). The noise is always estimated (as ``noise=None``).

    Args:
        y: slice values ``(B, S, nmax, 3)`` (the ``y`` of a stacked :class:`Measurements`).
        t: slice parameters ``(S, nmax)`` (radians), shared by the batch (a NumPy array).
        count: valid samples per slice ``(S,)`` (a NumPy array).
        level, min_effect, log_eps: as :func:`isotropy_test`.

    Returns:
        ``(isotropic, statistic, effect)``, each of shape ``(B,)``. ``isotropic`` is ``True``
        for every material when no axial slice has three samples (the test cannot run).
    """
    import jax.numpy as jnp
    from jax.scipy.special import gammaincc

    t = np.asarray(t, np.float64)
    count = np.asarray(count)
    S, nmax = t.shape
    valid = np.arange(nmax)[None, :] < count[:, None]
    axial = [s for s in range(0, S, 2) if count[s] >= 3]
    B = y.shape[0]
    if not axial:
        ones = jnp.ones((B,), bool)
        nan = jnp.full((B,), jnp.nan, y.dtype)
        return ones, nan, nan
    lum = jnp.einsum("bsnc,c->bsn", y, jnp.asarray(LUMA_WEIGHTS, y.dtype))
    mean = jnp.sum(jnp.where(valid, jnp.abs(lum), 0.0), axis=(1, 2)) / valid.sum()
    eps = log_eps * mean + np.finfo(np.float64).tiny ** 0.5
    l = jnp.log(jnp.maximum(lum, 0.0) + eps[:, None, None])
    # Noise: the interpolation residuals of the axial samples (fixed weights, static gathers).
    rows, ks, lefts, rights, wls, wrs = [], [], [], [], [], []
    for s in axial:
        n = int(count[s])
        wr = _interp_weights(t[s, :n])
        rows.append(np.full(n, s)), ks.append(np.arange(n))
        lefts.append(np.roll(np.arange(n), 1)), rights.append(np.roll(np.arange(n), -1))
        wls.append(1.0 - wr), wrs.append(wr)
    rows, ks, lefts, rights = (np.concatenate(a) for a in (rows, ks, lefts, rights))
    wl, wr = (jnp.asarray(np.concatenate(a), y.dtype) for a in (wls, wrs))
    r = (l[:, rows, ks] - (wl * l[:, rows, lefts] + wr * l[:, rows, rights])) / jnp.sqrt(1.0 + wl**2 + wr**2)
    sigma = jnp.maximum(_MAD_TO_SIGMA * jnp.median(jnp.abs(r), axis=1), 1e-6)
    # χ² statistic and effect size over the axial slices.
    amask = np.zeros((S, nmax), bool)
    for s in axial:
        amask[s, : count[s]] = True
    n_p = np.where(amask.any(axis=1), count, 1)
    slice_mean = jnp.sum(jnp.where(amask, l, 0.0), axis=2, keepdims=True) / n_p[None, :, None]
    ss = jnp.sum(jnp.where(amask, (l - slice_mean) ** 2, 0.0), axis=(1, 2))
    dof = int(sum(int(count[s]) - 1 for s in axial))
    nn = int(sum(int(count[s]) for s in axial))
    q = ss / sigma**2
    effect = jnp.sqrt(jnp.maximum(ss - dof * sigma**2, 0.0) / nn)
    pval = gammaincc(dof / 2.0, q / 2.0)
    isotropic = ~((pval < level) & (effect >= min_effect))
    return isotropic, q / dof, effect
