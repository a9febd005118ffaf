"""Colour science of the protocol metrics (PROTOCOL.md, Metrics): exposure, tone mapping, the sRGB
transfer curve, CIELAB under D65 and the per-pair colour differences ΔE76 and CIEDE2000, with
gradient-safe square roots and hue angles. :mod:`abrdf_jax.metrics._metrics` builds the metrics
from these.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from .._protocol import LUMA


# --------------------------------------------------------------------------------------------------
# Constants (float64 numpy, derived once at import).

#: Exposure luminance weights (PROTOCOL.md item 1, the literal values).
LUMA_WEIGHTS = np.array(LUMA)
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
# ... and decoding: linear segment at and below this encoded value (the standard's rounded
# 12.92 · 0.0031308; no 8- or 16-bit code value lies between the two).
_SRGB_DECODE_THRESHOLD = 0.04045

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


def srgb_decode(q: Float[ArrayLike, "..."], xp=jnp) -> Float[Array, "..."]:
    """The IEC 61966-2-1 sRGB decoding (EOTF), the inverse of :func:`srgb_encode`.

    ``q / 12.92`` for ``q <= 0.04045``, else ``((q + 0.055) / 1.055)^2.4``; the power is evaluated
    on the upper branch only (as in :func:`srgb_encode`), so the gradient is finite everywhere.
    Image readers decode 8- and 16-bit code values ``k / (2^bits − 1)`` with it
    (:mod:`abrdf_jax.btf._images`, through a float64 table of every code value).

    Args:
        q: encoded values, any shape (normally ``[0, 1]``).
        xp: the array namespace: ``jax.numpy`` (default) or ``numpy`` (a NumPy result in the
            input's precision, whatever JAX's default float).

    Returns:
        Linear values, same shape.
    """
    q = xp.asarray(q)
    hi = q > _SRGB_DECODE_THRESHOLD
    power = xp.power((xp.where(hi, q, 1.0) + 0.055) / 1.055, 2.4)
    return xp.where(hi, power, q / 12.92)


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
            jnp.where(
                hsum < 2.0 * jnp.pi, 0.5 * (hsum + 2.0 * jnp.pi), 0.5 * (hsum - 2.0 * jnp.pi)
            ),
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
