"""Evaluation metrics of ``PROTOCOL.md`` ("Metrics"): exposure, tone mapping, RMSE8/PSNR, ΔE, LogErr.

Every metric compares a reconstruction ``rec`` with a reference ``ref`` of ONE material. Both are arrays
of shape ``(..., 3)``: the last axis is linear RGB, every other axis indexes direction pairs (an ABRDF
table ``(81, 81, 3)`` or a list of pairs ``(P, 3)``). The pipeline (PROTOCOL.md, items 1–5):

1. exposure ``e = 0.18 / Ym`` from the reference alone, ``Ym`` the median over pairs of
   ``Y = 0.2126 R + 0.7152 G + 0.0722 B``; ``y = e · x`` for both tables;
2. Reinhard tone mapping ``t = y / (1 + y)``, negative ``y`` counted as 0;
3. ``q = 255 · srgb_encode(t)`` (no rounding): RMSE8 and PSNR;
4. ``t`` as linear sRGB (D65) → CIE XYZ → CIELAB (D65 white, ``Y = 1``): ΔE76 and ΔE2000, each the mean
   over direction pairs;
5. LogErr: the mean of ``|ln(1 + y_rec) − ln(1 + y_ref)|`` over all values (negatives counted as 0).

All functions are pure, jit-able and vmap-able, and differentiable with respect to ``rec`` with finite
gradients everywhere (they serve as losses): every square root, power and ``atan2`` that can meet an
exact zero is written with a double ``where`` (the value is selected by ``where`` and the argument of
the non-smooth function is replaced by a harmless one on the other branch, so that no ``inf · 0`` appears
in the backward pass). At a point where a metric is not differentiable (a distance of exactly zero, the
hue of a neutral colour, a negative value clamped to 0) the gradient returned is a finite one-sided or
zero subgradient.

Exact zeros: wherever ``rec == ref`` (elementwise, or the whole pair for ΔE) the error is set to exactly
0 by a ``where``, so identical tables give 0 (PSNR ``+inf``) under ``jit`` too, where the compiler's
fused multiply-adds would otherwise leave ~1e-15, and the gradient there is exactly 0.

Performance note: when jitting a loss, pass ``ref`` as an argument rather than closing over it. A
closed-over reference becomes a compile-time constant and XLA constant-folds the median's sort
(seconds for 6561 pairs).

The sRGB → XYZ matrix is derived at import, in float64 numpy, from the sRGB primaries and the D65
chromaticity ``(0.3127, 0.3290)`` exactly as colour-science's ``normalised_primary_matrix`` derives it
(not the 4-digit constants of IEC 61966-2-1, which colour-science's ``colour.sRGB_to_XYZ`` happens to use
by default: the two differ by about 1e-4 relative). The luminance weights of the exposure are the
protocol's literal ``0.2126, 0.7152, 0.0722``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError

__all__ = [
    "D65_XY",
    "SRGB_PRIMARIES_XY",
    "SRGB_TO_XYZ",
    "D65_WHITE_XYZ",
    "METRIC_KEYS",
    "expose",
    "tonemap",
    "srgb_encode",
    "srgb_to_lab",
    "rmse8",
    "psnr",
    "delta_e76",
    "delta_e2000",
    "log_error",
    "evaluate",
    "evaluate_batch",
    "summarize",
]

# --------------------------------------------------------------------------------------------------
# Constants (float64 numpy, derived once at import).

#: Exposure luminance weights (PROTOCOL.md item 1, the literal values).
LUMA_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])
#: Middle grey the median luminance is mapped to.
MIDDLE_GREY = 0.18
#: CIE 1931 2° chromaticity of D65, as in colour-science's ``CCS_ILLUMINANTS``.
D65_XY = np.array([0.3127, 0.3290])
#: Chromaticities of the sRGB (ITU-R BT.709) primaries R, G, B (rows).
SRGB_PRIMARIES_XY = np.array([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]])
#: Keys of :func:`evaluate`'s dictionary, in report order.
METRIC_KEYS = ("rmse8", "psnr", "de76", "de2000", "logerr")


def _xy_to_XYZ(xy: np.ndarray) -> np.ndarray:
    """Chromaticity ``(x, y)`` → tristimulus ``(x/y, 1, (1 − x − y)/y)`` (luminance 1)."""
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([x / y, np.ones_like(x), (1.0 - x - y) / y], axis=-1)


def _normalised_primary_matrix(primaries_xy: np.ndarray, white_xy: np.ndarray) -> np.ndarray:
    """RGB → XYZ matrix whose columns are the primaries scaled so that RGB ``(1, 1, 1)`` is the white.

    The derivation of SMPTE RP 177 / colour-science's ``normalised_primary_matrix``: the columns are the
    primaries' XYZ at unit luminance, scaled by ``S = P⁻¹ W``.
    """
    P = _xy_to_XYZ(primaries_xy).T  # columns: the primaries
    W = _xy_to_XYZ(white_xy)
    S = np.linalg.inv(P) @ W
    return P * S[None, :]


#: Linear sRGB → CIE XYZ (D65), derived from the primaries; row 1 gives Y.
SRGB_TO_XYZ = _normalised_primary_matrix(SRGB_PRIMARIES_XY, D65_XY)
#: The D65 reference white of CIELAB, ``Y = 1``.
D65_WHITE_XYZ = _xy_to_XYZ(D65_XY)
# CIELAB's f(u): cube root above (6/29)^3, the linear segment below (CIE 15:2004).
_LAB_EPS = (6.0 / 29.0) ** 3
_LAB_SLOPE = 841.0 / 108.0  # = (29/6)^2 / 3
_LAB_OFFSET = 16.0 / 116.0
# sRGB (IEC 61966-2-1) encoding: linear segment at and below this value.
_SRGB_THRESHOLD = 0.0031308

# --------------------------------------------------------------------------------------------------
# Safe primitives: finite values and finite gradients at exact zeros.


def _safe_sqrt(x: Array) -> Array:
    """``sqrt(x)`` for ``x > 0`` and 0 otherwise; the gradient at ``x <= 0`` is 0, not ``inf``/NaN.

    The naive ``sqrt`` has derivative ``1 / (2 sqrt(x))``, infinite at 0, and ``inf · 0 = NaN`` in any
    chain rule through it. The inner ``where`` feeds ``sqrt`` a harmless 1 on the zero branch so that
    the unselected branch's derivative is finite (the double-where of optax's ``safe_norm``).
    """
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _safe_hypot(a: Array, b: Array) -> Array:
    """``sqrt(a² + b²)`` by a safe square root (zero gradient at ``a = b = 0``)."""
    return _safe_sqrt(a * a + b * b)


def _safe_hue(b: Array, a: Array) -> Array:
    """Hue angle ``atan2(b, a)`` in ``[0, 2π)``, 0 where ``a = b = 0`` (Sharma et al. 2005, eq. 4).

    ``atan2``'s derivatives ``(−b, a) / (a² + b²)`` are 0/0 at the origin; there the angle is set to 0
    (the convention of the CIEDE2000 formula) with a zero gradient, and ``atan2`` is fed ``(0, 1)``.
    """
    nz = (a * a + b * b) > 0
    h = jnp.arctan2(jnp.where(nz, b, 0.0), jnp.where(nz, a, 1.0))
    return jnp.where(nz, jnp.mod(h, 2.0 * jnp.pi), 0.0)


# --------------------------------------------------------------------------------------------------
# Input handling (shapes are static: these checks run in Python, before and during tracing).


def _float_dtype(*xs: Array):
    dtype = jnp.result_type(*xs)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.zeros((), dtype=float).dtype  # the default float (float32 unless x64 is on)
    return dtype


def _check_table(x: Array, name: str) -> None:
    shape = jnp.shape(x)
    if len(shape) < 1 or shape[-1] != 3:
        raise InputError(f"{name} must have shape (..., 3) with RGB last; got shape {shape}")
    if int(np.prod(shape[:-1])) == 0:
        raise InputError(f"{name} has no direction pairs (shape {shape})")


def _prepare(rec: ArrayLike, ref: ArrayLike) -> tuple[Array, Array]:
    rec, ref = jnp.asarray(rec), jnp.asarray(ref)
    _check_table(rec, "rec")
    _check_table(ref, "ref")
    if rec.shape != ref.shape:
        raise InputError(f"rec and ref must have the same shape; got {rec.shape} and {ref.shape}")
    dtype = _float_dtype(rec, ref)
    return rec.astype(dtype), ref.astype(dtype)


# --------------------------------------------------------------------------------------------------
# The pipeline, item by item.


def expose(ref: Float[ArrayLike, "*pairs 3"]) -> Float[Array, ""]:
    """Exposure ``e = 0.18 / Ym`` set by the reference alone (PROTOCOL.md, Metrics item 1).

    ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` per direction pair and ``Ym`` its median over all pairs. If
    the median is not positive (0, or negative for unphysical data) the mean is used instead; if that is
    not positive either, ``e = 1`` (no exposure: there is nothing to expose by). A non-positive scale
    would flip or annihilate the data, so "0" in the protocol's rule is read as "not positive".

    Args:
        ref: reference table, shape ``(..., 3)``, linear RGB.

    Returns:
        The scalar exposure ``e``, in the dtype of ``ref`` (float for integer input).

    Raises:
        InputError: ``ref`` does not have RGB last or has no pairs.
    """
    ref = jnp.asarray(ref)
    _check_table(ref, "ref")
    ref = ref.astype(_float_dtype(ref))
    w = jnp.asarray(LUMA_WEIGHTS, dtype=ref.dtype)
    Y = jnp.sum(ref * w, axis=-1).reshape(-1)
    med = jnp.median(Y)
    mean = jnp.mean(Y)
    ym = jnp.where(med > 0, med, mean)
    ok = ym > 0
    return jnp.where(ok, MIDDLE_GREY / jnp.where(ok, ym, 1.0), 1.0).astype(ref.dtype)


def tonemap(y: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
    """Reinhard's global operator ``t = y / (1 + y)``, negative ``y`` counted as 0 (item 2).

    Smooth for ``y >= 0``; maps ``[0, ∞)`` onto ``[0, 1)`` without clipping. The gradient for ``y < 0``
    (and the one-sided gradient at ``y = 0``) is 0.

    Args:
        y: exposed linear values, any shape.

    Returns:
        Tone-mapped values ``t``, same shape.
    """
    y = jnp.asarray(y)
    yp = jnp.where(y > 0, y, 0.0)
    return yp / (1.0 + yp)


def srgb_encode(t: Float[ArrayLike, "..."]) -> Float[Array, "..."]:
    """The IEC 61966-2-1 sRGB transfer curve (inverse EOTF), no rounding or clipping (item 3).

    ``12.92 t`` for ``t <= 0.0031308``, else ``1.055 t^(1/2.4) − 0.055``. The power is evaluated on the
    upper branch only (its argument replaced by 1 on the lower one) so that the gradient is finite at
    ``t = 0`` (12.92 there); negative ``t`` follows the linear segment.

    Args:
        t: linear values, any shape (normally ``[0, 1]``).

    Returns:
        Encoded values, same shape.
    """
    t = jnp.asarray(t)
    hi = t > _SRGB_THRESHOLD
    power = 1.055 * jnp.power(jnp.where(hi, t, 1.0), 1.0 / 2.4) - 0.055
    return jnp.where(hi, power, 12.92 * t)


def _lab_f(u: Array) -> Array:
    """CIELAB's ``f(u)``: ``cbrt(u)`` above ``(6/29)^3``, else ``u · 841/108 + 16/116`` (safe cube root)."""
    hi = u > _LAB_EPS
    return jnp.where(hi, jnp.cbrt(jnp.where(hi, u, 1.0)), _LAB_SLOPE * u + _LAB_OFFSET)


def srgb_to_lab(t: Float[ArrayLike, "*pairs 3"]) -> Float[Array, "*pairs 3"]:
    """Linear sRGB (D65) → CIE XYZ → CIELAB with the D65 white at ``Y = 1`` (item 4).

    Args:
        t: linear sRGB values, shape ``(..., 3)`` (the tone-mapped ``t``; no transfer curve applied).

    Returns:
        ``(L*, a*, b*)``, shape ``(..., 3)``; ``L*`` is 100 at RGB ``(1, 1, 1)``.
    """
    t = jnp.asarray(t)
    M = jnp.asarray(SRGB_TO_XYZ, dtype=t.dtype)
    white = jnp.asarray(D65_WHITE_XYZ, dtype=t.dtype)
    # Elementwise products, not a matmul: exact on every backend (no TF32 on GPU).
    xyz = jnp.sum(t[..., None, :] * M, axis=-1)
    f = _lab_f(xyz / white)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return jnp.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)


def _exposed(rec: Array, ref: Array) -> tuple[Array, Array, Array]:
    """Exposed ``y_rec, y_ref`` and the mask ``rec == ref`` (elementwise).

    Every error is forced to exactly 0 where the inputs are equal. Mathematically it is 0 there anyway,
    but the compiler may contract ``a·e − b·e`` into ``fma(a, e, −b·e)`` on one side only and leave a
    residue of ~1e-15; the ``where`` also makes the gradient there exactly 0.
    """
    e = expose(ref)
    return rec * e, ref * e, rec == ref


def _mean_over_pairs(per_pair: Array, same: Array) -> Array:
    return jnp.mean(jnp.where(jnp.all(same, axis=-1), 0.0, per_pair))


def _rmse8_from_y(y_rec: Array, y_ref: Array, same: Array) -> Array:
    d = 255.0 * (srgb_encode(tonemap(y_rec)) - srgb_encode(tonemap(y_ref)))
    d = jnp.where(same, 0.0, d)
    return _safe_sqrt(jnp.mean(d * d))


def _psnr_from_rmse(r: Array) -> Array:
    pos = r > 0
    return jnp.where(pos, 20.0 * jnp.log10(255.0 / jnp.where(pos, r, 1.0)), jnp.inf)


def _de76_pairs(lab_rec: Array, lab_ref: Array) -> Array:
    d = lab_rec - lab_ref
    return _safe_sqrt(jnp.sum(d * d, axis=-1))


def _de2000_pairs(lab1: Array, lab2: Array) -> Array:
    """CIEDE2000 per pair (Sharma, Wu & Dalal, Color Res. Appl. 30(1), 2005, eqs. 1–22; kL = kC = kH = 1).

    Safe versions at zero chroma: ``C``, ``C'``, ``sqrt(C'1 C'2)`` and the ``sqrt(C̄⁷ / (C̄⁷ + 25⁷))``
    terms use :func:`_safe_sqrt`, the hue ``h'`` uses :func:`_safe_hue` (0 at ``a' = b = 0``, as the
    formula prescribes), and the final square root is safe at ``ΔE = 0``. Gradients are therefore finite
    for neutral colours and identical pairs; there the formula is not differentiable and the returned
    gradient is a subgradient with zero hue contribution.
    """
    L1, a1, b1 = lab1[..., 0], lab1[..., 1], lab1[..., 2]
    L2, a2, b2 = lab2[..., 0], lab2[..., 1], lab2[..., 2]
    pow25_7 = 25.0**7
    # eqs. 2-5: a' rescaled by G, chroma C' and hue h'
    c_bar = 0.5 * (_safe_hypot(a1, b1) + _safe_hypot(a2, b2))
    c_bar7 = c_bar**7
    G = 0.5 * (1.0 - _safe_sqrt(c_bar7 / (c_bar7 + pow25_7)))
    a1p, a2p = (1.0 + G) * a1, (1.0 + G) * a2
    c1p, c2p = _safe_hypot(a1p, b1), _safe_hypot(a2p, b2)
    h1p, h2p = _safe_hue(b1, a1p), _safe_hue(b2, a2p)
    # eqs. 8-11: differences
    dLp = L2 - L1
    dCp = c2p - c1p
    cprod = c1p * c2p
    neutral = cprod == 0
    dh = h2p - h1p
    dhp = jnp.where(dh > jnp.pi, dh - 2.0 * jnp.pi, jnp.where(dh < -jnp.pi, dh + 2.0 * jnp.pi, dh))
    dhp = jnp.where(neutral, 0.0, dhp)
    dHp = 2.0 * _safe_sqrt(cprod) * jnp.sin(0.5 * dhp)
    # eqs. 12-14: means
    Lbp = 0.5 * (L1 + L2)
    Cbp = 0.5 * (c1p + c2p)
    hsum = h1p + h2p
    hbp = jnp.where(
        neutral,
        hsum,
        jnp.where(
            jnp.abs(dh) <= jnp.pi,
            0.5 * hsum,
            jnp.where(hsum < 2.0 * jnp.pi, 0.5 * (hsum + 2.0 * jnp.pi), 0.5 * (hsum - 2.0 * jnp.pi)),
        ),
    )
    # eqs. 15-21: weights and rotation
    deg = jnp.pi / 180.0
    T = (
        1.0
        - 0.17 * jnp.cos(hbp - 30.0 * deg)
        + 0.24 * jnp.cos(2.0 * hbp)
        + 0.32 * jnp.cos(3.0 * hbp + 6.0 * deg)
        - 0.20 * jnp.cos(4.0 * hbp - 63.0 * deg)
    )
    dtheta = 30.0 * deg * jnp.exp(-(((hbp / deg - 275.0) / 25.0) ** 2))
    Cbp7 = Cbp**7
    RC = 2.0 * _safe_sqrt(Cbp7 / (Cbp7 + pow25_7))
    Lb2 = (Lbp - 50.0) ** 2
    SL = 1.0 + 0.015 * Lb2 / jnp.sqrt(20.0 + Lb2)
    SC = 1.0 + 0.045 * Cbp
    SH = 1.0 + 0.015 * Cbp * T
    RT = -jnp.sin(2.0 * dtheta) * RC
    # eq. 22 (the quadratic form is positive definite, |RT| < 2; the safe root absorbs rounding)
    xL, xC, xH = dLp / SL, dCp / SC, dHp / SH
    return _safe_sqrt(xL * xL + xC * xC + xH * xH + RT * xC * xH)


def _log_error_from_y(y_rec: Array, y_ref: Array, same: Array) -> Array:
    lr = jnp.log1p(jnp.where(y_rec > 0, y_rec, 0.0))
    lf = jnp.log1p(jnp.where(y_ref > 0, y_ref, 0.0))
    d = lr - lf
    # |d| with gradient 0 (not ±1) where d = 0, so that rec == ref is a stationary point.
    return jnp.mean(jnp.where(same | (d == 0), 0.0, jnp.abs(d)))


# --------------------------------------------------------------------------------------------------
# Public metrics.

def rmse8(rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]) -> Float[Array, ""]:
    """RMSE8: root mean square of ``q_ref − q_rec`` over all values, ``q = 255 · srgb_encode(t)``.

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure applied to both.

    Returns:
        Scalar, on the 0–255 scale (unrounded). Gradient 0 (finite) at ``rec == ref``.

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    rec, ref = _prepare(rec, ref)
    return _rmse8_from_y(*_exposed(rec, ref))


def psnr(rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]) -> Float[Array, ""]:
    """PSNR = ``20 log10(255 / RMSE8)`` dB.

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure applied to both.

    Returns:
        Scalar in dB; ``+inf`` exactly when RMSE8 is 0 (identical tone-mapped tables), returned
        explicitly (not by a division by zero), with a zero gradient there.

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    rec, ref = _prepare(rec, ref)
    return _psnr_from_rmse(_rmse8_from_y(*_exposed(rec, ref)))


def delta_e76(rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]) -> Float[Array, ""]:
    """ΔE76: mean over direction pairs of the Euclidean CIELAB distance of the tone-mapped tables.

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure applied to both.

    Returns:
        Scalar. The distance uses a safe norm: the gradient is finite (0) where a pair matches exactly.

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    rec, ref = _prepare(rec, ref)
    y_rec, y_ref, same = _exposed(rec, ref)
    de = _de76_pairs(srgb_to_lab(tonemap(y_rec)), srgb_to_lab(tonemap(y_ref)))
    return _mean_over_pairs(de, same)


def delta_e2000(
    rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]
) -> Float[Array, ""]:
    """ΔE2000 (CIEDE2000, Sharma et al. 2005, ``kL = kC = kH = 1``): mean over direction pairs.

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure applied to both.

    Returns:
        Scalar. Gradients are finite at zero chroma and at identical pairs (see ``_de2000_pairs``).

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    rec, ref = _prepare(rec, ref)
    y_rec, y_ref, same = _exposed(rec, ref)
    de = _de2000_pairs(srgb_to_lab(tonemap(y_rec)), srgb_to_lab(tonemap(y_ref)))
    return _mean_over_pairs(de, same)


def log_error(rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]) -> Float[Array, ""]:
    """LogErr: mean over all values of ``|ln(1 + y_rec) − ln(1 + y_ref)|`` of the exposed, untone-mapped y.

    Negative ``y`` counts as 0 here too, as in the tone mapping.

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure applied to both.

    Returns:
        Scalar. The gradient of ``|·|`` at 0 is 0 (finite).

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    rec, ref = _prepare(rec, ref)
    return _log_error_from_y(*_exposed(rec, ref))


def _evaluate(rec: Array, ref: Array) -> dict[str, Array]:
    y_rec, y_ref, same = _exposed(rec, ref)
    r = _rmse8_from_y(y_rec, y_ref, same)
    lab_rec, lab_ref = srgb_to_lab(tonemap(y_rec)), srgb_to_lab(tonemap(y_ref))
    return {
        "rmse8": r,
        "psnr": _psnr_from_rmse(r),
        "de76": _mean_over_pairs(_de76_pairs(lab_rec, lab_ref), same),
        "de2000": _mean_over_pairs(_de2000_pairs(lab_rec, lab_ref), same),
        "logerr": _log_error_from_y(y_rec, y_ref, same),
    }


@eqx.filter_jit
def evaluate(rec: Float[ArrayLike, "*pairs 3"], ref: Float[ArrayLike, "*pairs 3"]) -> dict[str, Array]:
    """All protocol metrics of one material, sharing the exposure and tone mapping (jitted).

    Args:
        rec: reconstruction, shape ``(..., 3)`` (direction pairs of one material, RGB last).
        ref: reference, same shape; it alone sets the exposure.

    Returns:
        ``{"rmse8", "psnr", "de76", "de2000", "logerr"}`` → scalar JAX arrays (see the functions of the
        same names).

    Raises:
        InputError: the shapes differ, RGB is not last, or there are no pairs.
    """
    return _evaluate(*_prepare(rec, ref))


@eqx.filter_jit
def evaluate_batch(
    rec: Float[ArrayLike, "m *pairs 3"], ref: Float[ArrayLike, "m *pairs 3"]
) -> dict[str, Array]:
    """:func:`evaluate` over a leading material axis (a ``vmap``; each material exposed by its own ref).

    Args:
        rec: reconstructions, shape ``(m, ..., 3)``.
        ref: references, same shape.

    Returns:
        The keys of :func:`evaluate`, each an array of shape ``(m,)``.

    Raises:
        InputError: the shapes differ, RGB is not last, or there is no material axis / no pairs.
    """
    rec, ref = _prepare(rec, ref)
    if rec.ndim < 2 or rec.shape[0] == 0:
        raise InputError(f"evaluate_batch needs shape (m, ..., 3) with m >= 1; got {rec.shape}")
    return jax.vmap(_evaluate)(rec, ref)


def summarize(results: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]]) -> dict[str, Array]:
    """Mean over materials of each metric (the protocol's reported figures).

    PSNR is the mean of the per-material PSNRs, as the protocol says. A material reconstructed exactly
    has PSNR ``+inf``, and then the mean is ``+inf`` too: infinities are kept, not dropped, so that a
    summary never hides a material (exact reconstructions only arise in self-tests). NaNs propagate.

    Args:
        results: either a list of :func:`evaluate` dictionaries (one per material) or one
            :func:`evaluate_batch` dictionary of ``(m,)`` arrays. Any set of keys is accepted.

    Returns:
        The same keys, each the mean over materials as a scalar JAX array.

    Raises:
        InputError: an empty list, or dictionaries with different keys.
    """
    if isinstance(results, Mapping):
        batch = {k: jnp.asarray(v) for k, v in results.items()}
    else:
        results = list(results)
        if not results:
            raise InputError("summarize: no results to summarize (empty list)")
        keys = set(results[0])
        for i, r in enumerate(results):
            if set(r) != keys:
                raise InputError(f"summarize: result {i} has keys {sorted(r)}, expected {sorted(keys)}")
        batch = {k: jnp.stack([jnp.asarray(r[k]) for r in results]) for k in results[0]}
    return {k: jnp.mean(v) for k, v in batch.items()}
