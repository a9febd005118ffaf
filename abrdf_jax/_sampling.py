"""Sampling a material along the slices: the measurement a device would record (PROTOCOL.md).

:func:`sample_model` evaluates a continuous model at the exact slice directions, :func:`sample_table`
interpolates a dense 81×81 table over azimuth; both are differentiable in α. :func:`sample` is the
public entry point (budget and pairs from a :class:`Config`, α from :class:`Params`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._errors import InputError
from ._finite import require_finite, when_traced
from ._grid import ring_indices
from ._measurements import Measurements
from ._params import Config, Params
from ._slices import KINDS, PROTOCOL_PAIRS, protocol_parameters, slice_angles, slice_directions


def _measured(t, y, count, pairs, counts) -> Measurements:
    """The sampled slices as a measurement, padding set to zero."""
    meas = Measurements(t, y, count, tuple(pairs), any(c > 0 for c in counts[0::2]))
    return meas.replace(y=jnp.where(meas.mask[..., None], y, 0.0))


def sample_model(model, counts, alpha, pairs=PROTOCOL_PAIRS, dtype=jnp.float32) -> Measurements:
    """Sample the PROTOCOL slices from a continuous model ``model(wi, wv) -> (..., 3)``.

    Args:
        model: callable of unit vectors (illumination, view), returning ABRDF values.
        counts: per-slice counts (see :func:`protocol_counts`); 0 leaves a slice unmeasured.
        alpha: slice offset in radians (traced: the samples are differentiable in α).
        pairs: elevation pairs in degrees.
    """
    t, count = protocol_parameters(counts, dtype=dtype)
    wi, wv = slice_directions(t, pairs, jnp.asarray(alpha, dtype))
    return _measured(t, model(wi, wv).astype(dtype), count, pairs, counts)


def sample_table(table, counts, alpha, pairs=PROTOCOL_PAIRS, dtype=jnp.float32) -> Measurements:
    """Sample the PROTOCOL slices from a dense 81×81 UBO table, interpolating over azimuth.

    Both azimuths are interpolated periodically and linearly on their rings (bilinear over
    ``(φi, φv)``, :func:`table_corners`), so the result is differentiable in α. The elevations
    must be UBO rings.
    """
    table = jnp.asarray(table, dtype)
    if table.shape != (81, 81, 3):
        raise InputError(f"table must have shape (81, 81, 3), got {table.shape}")
    t, count = protocol_parameters(counts, dtype=dtype)
    y = interpolate_table(table, table_corners(t, jnp.asarray(alpha, dtype), pairs))
    return _measured(t, y, count, pairs, counts)


def table_corners(t, alpha, pairs):
    """Where slice positions ``t`` (``(S, n)``, radians) fall on the 81×81 grid: bilinear corners.

    Returns ``(i0, i1, v0, v1, a, b)``, each ``(S, n)``: grid rows (illumination) ``i0, i1`` and
    columns (view) ``v0, v1`` of the four corners on the rings of ``pairs[s // 2]``, and the
    weights ``a`` (of ``i1``) and ``b`` (of ``v1``). Differentiable in ``alpha`` and ``t``.
    """
    parts = []
    for s in range(t.shape[0]):
        ti, tv = pairs[s // 2]
        ri, rv = ring_indices(ti), ring_indices(tv)
        pi_, pv = slice_angles(KINDS[s % 2], t[s], alpha)
        ii0, ii1, wi_ = _ring_weights(pi_, len(ri))
        vv0, vv1, wv_ = _ring_weights(pv, len(rv))
        ri, rv = jnp.asarray(ri), jnp.asarray(rv)
        parts.append((ri[ii0], ri[ii1], rv[vv0], rv[vv1], wi_, wv_))
    return tuple(jnp.stack(x) for x in zip(*parts))


def interpolate_table(values, corners):
    """Bilinear interpolation of ``values`` (``(81, 81, ...)``) at :func:`table_corners`:
    ``(S, n, ...)`` (the trailing axes of ``values`` kept)."""
    i0, i1, v0, v1, a, b = corners
    extra = (1,) * (values.ndim - 2)
    a, b = a.reshape(a.shape + extra), b.reshape(b.shape + extra)
    v00, v01 = values[i0, v0], values[i0, v1]
    v10, v11 = values[i1, v0], values[i1, v1]
    return (1 - a) * ((1 - b) * v00 + b * v01) + a * ((1 - b) * v10 + b * v11)


def _ring_weights(phi, n):
    x = jnp.mod(phi, 2 * jnp.pi) * n / (2 * jnp.pi)
    k0 = jnp.floor(x)
    w = x - k0
    k0 = k0.astype(jnp.int32) % n
    return k0, (k0 + 1) % n, w


def sample(
    source,
    config: Config | None = None,
    params: Params | None = None,
    *,
    as_measurements: bool = False,
):
    """Sample the PROTOCOL slices of ``config.budget`` from a model or a dense table.

    Args:
        source: a callable ``model(wi, wv) -> (..., 3)`` (exact angles) or an ``(81, 81, 3)``
            table (interpolated over azimuth on the UBO rings).
        config: gives the budget and the elevation pairs.
        params: gives α (differentiable: the sample values follow α).
        as_measurements: return the grouped :class:`Measurements` (JAX, differentiable) instead
            of flat :class:`Samples`.

    Raises:
        InputError: a table, a model's values or α holding NaN or infinity (when concrete;
            inside a ``jit`` the compiled call raises a ``RuntimeError``, :mod:`abrdf_jax._finite`).
    """
    config = config or Config()
    params = params or Params.default(config)
    alpha = require_finite(params.alpha, "sample: params.alpha")
    if callable(source) and not hasattr(source, "shape"):
        dtype = params.alpha.dtype
        meas = sample_model(source, config.counts, alpha, config.pairs, dtype=dtype)
        if isinstance(meas.y, jax.core.Tracer):  # concrete: refused by Measurements itself
            meas = meas.replace(y=when_traced(meas.y, "sample: the model's values"))
    else:
        arr = require_finite(jnp.asarray(source), "sample: the source table")
        meas = sample_table(arr, config.counts, alpha, config.pairs, dtype=arr.dtype)
    if as_measurements:
        return meas
    return meas.to_samples(alpha_deg=params.alpha_deg)
