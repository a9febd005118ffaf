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

from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from .._grouping import group_arrays
from .._per_layout import layout_of, per_layout, stacked_values
from .._protocol import LUMA
from .._smoothing import neighbours, noise_level
from ._chi2 import chi2_critical, chi2_sf

if TYPE_CHECKING:  # JAX pytrees; one material's test runs in numpy on their fields
    from .._measurements import Measurements, Samples


def _jnp():
    """``jax.numpy``, imported where a batch runs in JAX (the one-material test needs none)."""
    import jax.numpy as jnp

    return jnp


#: Default significance level and minimum effect (RMS log variation of the axial slices).
LEVEL = 1e-3
MIN_EFFECT = 0.02
#: ε of the test's log transform, relative to the mean luminance: small, so that multiplicative
#: noise keeps one standard deviation in log space down to samples 1000x darker than the mean
#: (the pipeline's 1 % would damp the noise of dark samples and unbalance the pooled estimate).
LOG_EPS = 1e-4


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
        out = {f: getattr(self, f) for f in _REPORT_FIELDS}  # scalars: no deep copy needed
        for k, v in out.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
        out["per_pair"] = [dict(d, pair=list(d["pair"])) for d in self.per_pair]
        return out


_REPORT_FIELDS = tuple(f.name for f in dataclasses.fields(IsotropyReport))


def _log_luminance(y, valid, log_eps: float, xp=None):
    """``ln(Y + ε)`` of slice values ``y`` ``(B, S, nmax, 3)``, ``ε = log_eps · mean |Y|`` per material.

    ``xp``: the array module, ``jax.numpy`` (a batch, in JAX) or ``numpy`` (one material on the
    host: no dispatch of a dozen small operations; the same formulas, one copy)."""
    xp = xp or _jnp()
    lum = xp.einsum("bsnc,c->bsn", y, xp.asarray(LUMA, y.dtype))
    mean = xp.sum(xp.where(valid, xp.abs(lum), 0.0), axis=(1, 2)) / max(int(valid.sum()), 1)
    eps = log_eps * mean + np.finfo(np.float64).tiny ** 0.5
    return xp.log(xp.maximum(lum, 0.0) + eps[:, None, None])


def _noise(logl, t: np.ndarray, count: np.ndarray, rows, xp=None):
    """Noise ``σ`` ``(B,)``: ``1.4826 · median |r|`` of the normalised residuals ``r`` of every
    sample of the slices ``rows`` against the linear interpolation of its two neighbours (a unit
    independent noise gives residuals of unit variance; the estimator of
    :func:`abrdf_jax._smoothing.noise_level`, one copy); ``nan`` when no slice has 3 samples."""
    xp = xp or _jnp()
    rows = [s for s in rows if count[s] >= 3]
    if not rows:
        return xp.full((logl.shape[0],), np.nan, logl.dtype)
    counts = np.where(np.isin(np.arange(len(count)), rows), count, 0)  # the other slices: none
    left, right, wl, wr, valid, slice_of = neighbours(np.asarray(t, np.float64), counts, np)
    nb = (left, right, wl.astype(logl.dtype), wr.astype(logl.dtype), valid, slice_of)
    return noise_level(logl.reshape(*logl.shape[:-2], -1, 1), nb, xp)


def _axial_sums(logl, count: np.ndarray, xp=None):
    """Sum of squared deviations from the slice mean of every axial slice with ≥ 3 samples:
    ``(B, S)`` (0 elsewhere), and the mask of those slices ``(S,)``."""
    xp = xp or _jnp()
    S, nmax = logl.shape[1:]
    used = np.array([s % 2 == 0 and count[s] >= 3 for s in range(S)])
    amask = used[:, None] & (np.arange(nmax)[None, :] < count[:, None])
    n_p = np.where(used, count, 1)
    slice_mean = xp.sum(xp.where(amask, logl, 0.0), axis=2, keepdims=True) / n_p[None, :, None]
    return xp.sum(xp.where(amask, (logl - slice_mean) ** 2, 0.0), axis=2), used


def estimate_noise(meas: "Measurements", log_eps: float = None, slices: str = "axial") -> float:
    """Robust noise level (log units) from the slices' high-frequency residuals.

    Args:
        meas: the grouped measurement.
        log_eps: ``ε`` of the log transform, relative to the mean luminance.
        slices: ``"axial"`` (default; the diagonal slices when no axial slice was measured),
            ``"diagonal"`` or ``"all"``: which slices' residuals enter the median.

    Returns:
        ``σ`` in log units (``nan`` when no slice has 3 samples).
    """
    return estimate_noise_many([meas], log_eps, slices)[0]


def estimate_noise_many(measurements, log_eps: float | None = None, slices: str = "axial"):
    """:func:`estimate_noise` of every measurement (a list of floats): those that share a
    layout in one vectorised pass on the host (:func:`abrdf_jax._per_layout.per_layout`; the
    same numbers as one by one)."""
    log_eps = LOG_EPS if log_eps is None else log_eps
    if slices not in ("axial", "diagonal", "all"):
        raise InputError(f"slices must be 'axial', 'diagonal' or 'all', got {slices!r}")

    def run(ks):
        m = measurements[ks[0]]
        logl = _log_luminance(
            stacked_values(measurements, ks), np.asarray(m.mask)[None], log_eps, np
        )
        return [float(v) for v in np.reshape(_estimate(m, logl, slices), -1)]

    return per_layout([layout_of(m) for m in measurements], run)


def _rows(count: np.ndarray, slices: str) -> tuple:
    """The slices (with ≥ 3 samples) whose residuals enter the noise estimate ``slices``."""
    if slices == "axial" and not np.any(count[0::2] >= 3):
        slices = "diagonal"
    start, step = {"axial": (0, 2), "diagonal": (1, 2), "all": (0, 1)}[slices]
    return tuple(s for s in range(start, len(count), step) if count[s] >= 3)


def _estimate(meas, logl, slices: str):
    """The noise ``σ`` ``(B,)`` of log luminances ``logl`` ``(B, S, nmax)`` of ``meas``'s layout."""
    cnt = np.asarray(meas.count)
    return _noise(logl, np.asarray(meas.t, np.float64), cnt, _rows(cnt, slices), np)


def isotropy_test(
    samples: "Samples | Measurements",
    *,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    alpha_deg: float | None = None,
    log_eps: float = LOG_EPS,
    estimate: float | None = None,
) -> IsotropyReport:
    """Decide from the axial slices whether a material is isotropic (module docstring).

    Args:
        samples: measured samples (grouped here, α estimated unless ``alpha_deg``) or grouped
            :class:`Measurements`.
        noise: relative noise of one sample (e.g. 0.03 for 3 %), if known; default:
            :func:`estimate_noise`.
        level: significance level of the χ² test.
        min_effect: smallest RMS variation (log units) of the axial slices that counts as
            anisotropy worth modelling.
        alpha_deg: slice offset for grouping :class:`Samples`.
        log_eps: ``ε`` of the log transform, relative to the mean luminance (:data:`LOG_EPS`).
        estimate: without ``noise``, :func:`estimate_noise` of ``samples`` (grouped) with this
            ``log_eps``, when already at hand (a folder's, :func:`estimate_noise_many`): the
            report is the same as when the test estimates it.

    Returns:
        An :class:`IsotropyReport`.

    Raises:
        InputError: on a negative ``noise``, a ``level`` outside (0, 1) or a negative ``min_effect``.
    """
    _check_test(noise, level, min_effect)
    if all(hasattr(samples, f) for f in ("t", "y", "count", "pairs")):
        pass  # grouped: Measurements (or the numpy slices of the command line)
    elif all(hasattr(samples, f) for f in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")):
        samples, _ = group_arrays(samples, alpha_deg, dtype=np.float64)
    else:
        raise InputError(f"samples must be Samples or Measurements, got {type(samples).__name__}")
    return isotropy_tests(
        [samples], noise=noise, level=level, min_effect=min_effect, log_eps=log_eps,
        estimates=None if estimate is None else [estimate],
    )[0]  # fmt: skip


def _check_test(noise, level, min_effect) -> None:
    if noise is not None and not (math.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a finite relative level >= 0, got {noise!r}")
    if not 0 < level < 1:
        raise InputError(f"level must lie in (0, 1), got {level!r}")
    if not min_effect >= 0:
        raise InputError(f"min_effect must be >= 0, got {min_effect!r}")


def isotropy_tests(
    measurements,
    *,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    log_eps: float = LOG_EPS,
    estimates=None,
) -> list[IsotropyReport]:
    """:func:`isotropy_test` of every grouped measurement (a list of reports): those that share
    a layout in one vectorised pass on the host (:func:`abrdf_jax._per_layout.per_layout`, as
    :func:`estimate_noise_many`; the same reports as one by one, ``tests/test_select.py``).
    ``estimates``: each measurement's noise estimate, if at hand (else estimated here)."""
    _check_test(noise, level, min_effect)
    estimates = [None] * len(measurements) if estimates is None else list(estimates)

    def run(ks):
        meas = measurements[ks[0]]
        cnt = np.asarray(meas.count)
        measured = bool(np.any(cnt[0::2] >= 3))  # an axial slice to test
        estimate = noise is None and any(estimates[k] is None for k in ks)
        logl = sums = used = None
        if measured or estimate:
            y = stacked_values(measurements, ks)
            logl = _log_luminance(y, np.asarray(meas.mask)[None], log_eps, np)
        if measured:
            sums, used = _axial_sums(logl, cnt, np)
        if estimate:  # one pass for the layout
            found = _estimate(meas, logl, "axial")
        out = []
        for j, k in enumerate(ks):
            if noise is None:
                est = found[j] if estimates[k] is None else estimates[k]
                sigma, source = float(est), "estimated"
            else:
                sigma, source = float(noise), "given"
            row = None if sums is None else np.asarray(sums[j], np.float64)
            out.append(_report(measurements[k], cnt, row, used, sigma, source, level, min_effect))
        return out

    return per_layout([layout_of(m) for m in measurements], run)


def _report(meas, cnt, sums, used, sigma, source, level, min_effect) -> IsotropyReport:
    """The report of one material from its axial slices' sums of squared deviations ``sums``
    ``(S,)`` (``None``: no axial slice with 3 samples) and its noise ``sigma``."""
    floor = 1e-6  # log units: float32 rounding of constant slices stays below it
    sigma = max(sigma, floor) if math.isfinite(sigma) else floor
    common = dict(noise=sigma, noise_source=source, level=level, min_effect=min_effect)
    if sums is None:
        return IsotropyReport(
            isotropic=True,
            measured=False,
            statistic=float("nan"),
            p_value=float("nan"),
            dof=0,
            effect=float("nan"),
            per_pair=(),
            **common,
            reason="no axial slice was measured: the material is taken as isotropic",
        )
    per_pair = [
        dict(
            pair=tuple(pair),
            n=int(cnt[2 * p]),
            statistic=float(sums[2 * p] / sigma**2 / (cnt[2 * p] - 1)),
            effect=float(np.sqrt(max(sums[2 * p] - (cnt[2 * p] - 1) * sigma**2, 0.0) / cnt[2 * p])),
        )
        for p, pair in enumerate(meas.pairs)
        if used[2 * p]
    ]
    ss, dof, nn = float(sums[used].sum()), int((cnt[used] - 1).sum()), int(cnt[used].sum())
    q = ss / sigma**2
    # The raw RMS includes the noise: remove its expected share (n_p - 1) σ² per pair.
    effect = math.sqrt(max(ss - dof * sigma**2, 0.0) / nn)
    stat = q / dof
    pval = float(chi2_sf(q, dof))
    significant = pval < level
    material = effect >= min_effect
    iso = not (significant and material)
    if iso and not significant:
        why = (
            f"the axial slices vary no more than the noise (chi2/dof {stat:.3g}, p = {pval:.3g} >= {level:g}, "
            f"noise {sigma:.3g} {source})"
        )
    elif iso:
        why = (
            f"the axial slices vary significantly (p = {pval:.3g}) but only by {effect:.3g} RMS in log units "
            f"(< {min_effect:g}): too little to model"
        )
    else:
        why = (
            f"the axial slices vary by {effect:.3g} RMS in log units, {stat:.3g}x the noise variance "
            f"(p = {pval:.3g} < {level:g}, noise {sigma:.3g} {source})"
        )
    return IsotropyReport(
        isotropic=iso,
        measured=True,
        statistic=stat,
        p_value=pval,
        dof=dof,
        effect=effect,
        per_pair=tuple(per_pair),
        reason=("isotropic: " if iso else "anisotropic: ") + why,
        **common,
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
    t = np.asarray(t, np.float64)
    count = np.asarray(count)
    S, nmax = t.shape
    B = y.shape[0]
    jnp = _jnp()
    if not any(count[s] >= 3 for s in range(0, S, 2)):
        nan = jnp.full((B,), jnp.nan, y.dtype)
        return jnp.ones((B,), bool), nan, nan
    logl = _log_luminance(y, np.arange(nmax)[None, :] < count[:, None], log_eps)
    sigma = jnp.maximum(_noise(logl, t, count, range(0, S, 2)), 1e-6)
    sums, used = _axial_sums(logl, count)
    ss = jnp.sum(sums, axis=1)
    dof, nn = int((count[used] - 1).sum()), int(count[used].sum())
    q = ss / sigma**2
    effect = jnp.sqrt(jnp.maximum(ss - dof * sigma**2, 0.0) / nn)
    # chi2_sf(q, dof) < level exactly when q exceeds the critical value: one root per layout
    isotropic = ~((q > chi2_critical(level, dof)) & (effect >= min_effect))
    return isotropic, q / dof, effect
