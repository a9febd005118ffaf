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

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ._color import _de76_pairs, _de2000_pairs, _prepare, _safe_sqrt
from ._color import expose, srgb_encode, srgb_to_lab, tonemap

_Pairs = Float[ArrayLike, "*pairs 3"]  # rec and ref: direction pairs of one material, RGB last


def _exposed(rec: Array, ref: Array) -> tuple[Array, Array, Array]:
    """Exposed ``y_rec, y_ref`` and the mask ``rec == ref`` (elementwise; "Exact zeros" above)."""
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


def _log_error_from_y(y_rec: Array, y_ref: Array, same: Array) -> Array:
    lr = jnp.log1p(jnp.where(y_rec > 0, y_rec, 0.0))
    lf = jnp.log1p(jnp.where(y_ref > 0, y_ref, 0.0))
    d = lr - lf
    # |d| with gradient 0 (not ±1) where d = 0, so that rec == ref is a stationary point.
    return jnp.mean(jnp.where(same | (d == 0), 0.0, jnp.abs(d)))


# --------------------------------------------------------------------------------------------------
# Public metrics: ``rec`` and ``ref`` as in the module docstring; each raises InputError if the shapes
# differ, RGB is not last, or there are no pairs.


def rmse8(rec: _Pairs, ref: _Pairs) -> Float[Array, ""]:
    """RMSE8: root mean square of ``q_ref − q_rec`` over all values, ``q = 255 · srgb_encode(t)``.

    Returns a scalar on the 0–255 scale (unrounded); gradient 0 (finite) at ``rec == ref``.
    """
    rec, ref = _prepare(rec, ref)
    return _rmse8_from_y(*_exposed(rec, ref))


def psnr(rec: _Pairs, ref: _Pairs) -> Float[Array, ""]:
    """PSNR = ``20 log10(255 / RMSE8)`` dB.

    ``+inf`` exactly when RMSE8 is 0 (identical tone-mapped tables), returned explicitly (not by a
    division by zero), with a zero gradient there.
    """
    rec, ref = _prepare(rec, ref)
    return _psnr_from_rmse(_rmse8_from_y(*_exposed(rec, ref)))


def delta_e76_pairs(rec: _Pairs, ref: _Pairs) -> Float[Array, "*pairs"]:
    """ΔE76 of each direction pair: the Euclidean CIELAB distance of the tone-mapped tables,
    0 where a pair matches exactly (the map whose mean is :func:`delta_e76`; for figures).
    """
    rec, ref = _prepare(rec, ref)
    y_rec, y_ref, same = _exposed(rec, ref)
    de = _de76_pairs(srgb_to_lab(tonemap(y_rec)), srgb_to_lab(tonemap(y_ref)))
    return jnp.where(jnp.all(same, axis=-1), 0.0, de)


def delta_e76(rec: _Pairs, ref: _Pairs) -> Float[Array, ""]:
    """ΔE76: mean over direction pairs of the Euclidean CIELAB distance of the tone-mapped tables.

    The distance uses a safe norm: the gradient is finite (0) where a pair matches exactly.
    """
    return jnp.mean(delta_e76_pairs(rec, ref))


def delta_e2000(rec: _Pairs, ref: _Pairs) -> Float[Array, ""]:
    """ΔE2000 (CIEDE2000, Sharma et al. 2005, ``kL = kC = kH = 1``): mean over direction pairs.

    Gradients are finite at zero chroma and at identical pairs (see ``_de2000_pairs``).
    """
    rec, ref = _prepare(rec, ref)
    y_rec, y_ref, same = _exposed(rec, ref)
    de = _de2000_pairs(srgb_to_lab(tonemap(y_rec)), srgb_to_lab(tonemap(y_ref)))
    return _mean_over_pairs(de, same)


def log_error(rec: _Pairs, ref: _Pairs) -> Float[Array, ""]:
    """LogErr: mean over all values of ``|ln(1 + y_rec) − ln(1 + y_ref)|`` of the exposed, untone-mapped y.

    Negative ``y`` counts as 0 here too, as in the tone mapping; the gradient of ``|·|`` at 0 is 0.
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
def evaluate(rec: _Pairs, ref: _Pairs) -> dict[str, Array]:
    """All protocol metrics of one material, sharing the exposure and tone mapping (jitted).

    Returns ``{"rmse8", "psnr", "de76", "de2000", "logerr"}`` → scalar JAX arrays (see the functions
    of the same names).
    """
    return _evaluate(*_prepare(rec, ref))


@eqx.filter_jit
def evaluate_batch(
    rec: Float[ArrayLike, "m *pairs 3"], ref: Float[ArrayLike, "m *pairs 3"]
) -> dict[str, Array]:
    """:func:`evaluate` over a leading material axis ``m`` (a ``vmap``; each material exposed by its
    own ref): the keys of :func:`evaluate`, each an array of shape ``(m,)``; also raises without a
    material axis."""
    rec, ref = _prepare(rec, ref)
    if rec.ndim < 2 or rec.shape[0] == 0:
        raise InputError(f"evaluate_batch needs shape (m, ..., 3) with m >= 1; got {rec.shape}")
    return jax.vmap(_evaluate)(rec, ref)


def summarize(
    results: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
) -> dict[str, Array]:
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
                raise InputError(
                    f"summarize: result {i} has keys {sorted(r)}, expected {sorted(keys)}"
                )
        batch = {k: jnp.stack([jnp.asarray(r[k]) for r in results]) for k in results[0]}
    return {k: jnp.mean(v) for k, v in batch.items()}
