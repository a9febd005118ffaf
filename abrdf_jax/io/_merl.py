"""MERL BRDF database files (Matusik, Pfister, Brand & McMillan, "A data-driven reflectance
model", SIGGRAPH 2003) and nearest-bin evaluation of such a BRDF.

File layout (``.binary``): three little-endian int32 ``(90, 90, 180)`` — the number of θh, θd and
φd bins — then ``3·90·90·180`` little-endian float64, channel-major (all R, then all G, then all B);
within a channel the value of bin ``(h, d, p)`` sits at ``(h·90 + d)·180 + p``. Physical BRDF
values are the stored values times ``(1/1500, 1.15/1500, 1.66/1500)`` for R, G, B. Negative stored
values mark bins without measured data.

Binning (Rusinkiewicz half/difference angles, see :func:`abrdf_jax._grid.half_diff`):
``h = ⌊sqrt(θh / (π/2)) · 90⌋``, ``d = ⌊θd / (π/2) · 90⌋``, ``p = ⌊(φd mod π) / π · 180⌋`` (φd is
reduced to ``[0, π)`` by reciprocity), each clamped to its range.
"""

import os
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._atomic import _check_readable, atomic_write
from .._errors import InputError, located
from .._grid import half_diff

#: Bins of a MERL BRDF: (θh, θd, φd).
MERL_BINS = (90, 90, 180)
#: Shape of the array returned by :func:`read_merl_binary`.
MERL_SHAPE = (*MERL_BINS, 3)
#: Stored value × scale = physical BRDF value, for R, G, B.
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])

_HEADER_BYTES = 12
_N_PER_CHANNEL = MERL_BINS[0] * MERL_BINS[1] * MERL_BINS[2]
_FILE_BYTES = _HEADER_BYTES + 3 * _N_PER_CHANNEL * 8


def read_merl_binary(path: str | os.PathLike) -> np.ndarray:
    """Read a MERL ``.binary`` BRDF file.

    Args:
        path: the file (str or path-like).

    Returns:
        float64 numpy array of shape ``(90, 90, 180, 3)`` indexed ``[θh bin, θd bin, φd bin,
        channel]``, in physical BRDF units (no cosine factor). Bins without data keep their
        negative value, so that callers can tell them apart (:func:`merl_lookup` returns 0 there).

    Raises:
        InputError: the file is missing or unreadable, its header does not give ``(90, 90, 180)``,
            its size is not the size that header implies, or it holds NaN or infinite values.
    """
    path = Path(path)
    _check_readable(path)
    try:
        with open(path, "rb") as f:
            header = f.read(_HEADER_BYTES)
            if len(header) < _HEADER_BYTES:
                raise located(
                    f"too short for a MERL header: {len(header)} bytes, expected {_HEADER_BYTES} "
                    f"then {_FILE_BYTES - _HEADER_BYTES} bytes of data",
                    path,
                )
            dims = tuple(int(x) for x in np.frombuffer(header, dtype="<i4"))
            if dims != MERL_BINS:
                raise located(
                    f"MERL header gives dimensions {dims}, "
                    f"expected {MERL_BINS} (theta_h, theta_d, phi_d)",
                    path,
                )
            size = os.fstat(f.fileno()).st_size
            if size != _FILE_BYTES:
                raise located(
                    f"file has {size} bytes, expected {_FILE_BYTES} "
                    f"(12-byte header + 3 x {_N_PER_CHANNEL} float64) for dimensions {MERL_BINS}",
                    path,
                )
            raw = np.frombuffer(f.read(), dtype="<f8")
    except InputError:
        raise
    except OSError as e:
        raise located(f"cannot read: {e.strerror or e}", path) from e
    if raw.size != 3 * _N_PER_CHANNEL:  # the file changed while we read it
        raise located(
            f"read {raw.size * 8} bytes of data, expected {_FILE_BYTES - _HEADER_BYTES}", path
        )
    bad = ~np.isfinite(raw)
    if bad.any():
        raise located(f"holds {int(bad.sum())} NaN or infinite value(s)", path)
    brdf = np.moveaxis(raw.reshape(3, *MERL_BINS), 0, -1) * MERL_SCALE
    return np.ascontiguousarray(brdf, dtype=np.float64)


def write_merl_binary(path: str | os.PathLike, brdf) -> None:
    """Write a BRDF as a MERL ``.binary`` file, atomically (inverse of :func:`read_merl_binary`).

    Args:
        path: the destination (str or path-like).
        brdf: array-like of shape ``(90, 90, 180, 3)`` in physical units; negative values mark
            bins without data and are written as they are (scaled).

    Raises:
        InputError: wrong shape, NaN or infinite values, or the file cannot be written.
    """
    path = Path(path)
    arr = np.asarray(brdf, dtype=np.float64)
    if arr.shape != MERL_SHAPE:
        raise InputError(f"cannot write {path}: BRDF has shape {arr.shape}, expected {MERL_SHAPE}")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise InputError(
            f"cannot write {path}: BRDF holds {int(bad.sum())} NaN or infinite value(s)"
        )
    raw = np.moveaxis(arr / MERL_SCALE, -1, 0)  # channel-major
    with atomic_write(path, "wb") as f:
        f.write(np.asarray(MERL_BINS, dtype="<i4").tobytes())
        f.write(np.ascontiguousarray(raw, dtype="<f8").tobytes())


def merl_bin_indices(
    wi: Float[Array, "... 3"], wv: Float[Array, "... 3"]
) -> tuple[Array, Array, Array]:
    """MERL bin indices ``(θh, θd, φd)`` of direction pairs (int32 arrays of the broadcast shape).

    Args:
        wi, wv: unit vectors (z = surface normal), broadcastable against each other.
    """
    hd = half_diff(wi, wv)
    th, td, pd = hd[..., 0], hd[..., 2], hd[..., 3]
    half_pi = jnp.pi / 2
    ih = jnp.floor(jnp.sqrt(jnp.clip(th, 0.0, half_pi) / half_pi) * MERL_BINS[0])
    idd = jnp.floor(td / half_pi * MERL_BINS[1])
    # Reciprocity: φd and φd + π are the same configuration. At θd = 0 (wi = wv) φd is undefined
    # and the rounding of the rotations leaves θd ~ sqrt(machine eps) with a random φd; below
    # that noise level pin φd to 0 so the bin is deterministic.
    noise = 8.0 * float(np.sqrt(jnp.finfo(hd.dtype).eps))
    pd = jnp.where(td < noise, 0.0, jnp.mod(pd, jnp.pi))
    ip = jnp.floor(pd / jnp.pi * MERL_BINS[2])
    return tuple(jnp.clip(i, 0, n - 1).astype(jnp.int32) for i, n in zip((ih, idd, ip), MERL_BINS))


def merl_lookup(
    brdf: Float[Array, "90 90 180 3"], wi: Float[Array, "... 3"], wv: Float[Array, "... 3"]
) -> Float[Array, "... 3"]:
    """Evaluate a MERL-binned BRDF (no cosine factor) at direction pairs, nearest bin.

    Pure JAX: works under ``jit`` and ``vmap``, differentiable with respect to ``brdf`` (the
    lookup is piecewise constant in the directions, so their gradient is zero).

    Args:
        brdf: shape ``(90, 90, 180, 3)``, as returned by :func:`read_merl_binary`.
        wi, wv: unit illumination and view vectors (z = surface normal), shapes broadcastable
            to a common ``(..., 3)``.

    Returns:
        shape ``(..., 3)``: the bin value, 0 where either direction is at or below the horizon
        (``z <= 0``) or the stored value is negative (no data).

    Raises:
        InputError: ``brdf`` is not ``(90, 90, 180, 3)`` or a direction's last axis is not 3.
    """
    brdf = jnp.asarray(brdf)
    wi = jnp.asarray(wi)
    wv = jnp.asarray(wv)
    if brdf.shape != MERL_SHAPE:
        raise InputError(f"merl_lookup: brdf has shape {brdf.shape}, expected {MERL_SHAPE}")
    for name, w in (("wi", wi), ("wv", wv)):
        if w.ndim == 0 or w.shape[-1] != 3:
            raise InputError(f"merl_lookup: {name} has shape {w.shape}, expected (..., 3)")
    try:
        shape = jnp.broadcast_shapes(wi.shape, wv.shape)
    except ValueError as e:
        raise InputError(f"merl_lookup: wi {wi.shape} and wv {wv.shape} do not broadcast") from e
    dtype = jnp.result_type(wi.dtype, wv.dtype, jnp.float32)
    wi = jnp.broadcast_to(wi, shape).astype(dtype)
    wv = jnp.broadcast_to(wv, shape).astype(dtype)
    return _lookup(brdf, wi, wv)


@jax.jit
def _lookup(brdf, wi, wv):
    # One compiled kernel per shape: eager op-by-op dispatch costs more than the lookup itself.
    ih, idd, ip = merl_bin_indices(wi, wv)
    value = brdf[ih, idd, ip]
    above = (wi[..., 2] > 0) & (wv[..., 2] > 0)
    return jnp.where(above[..., None] & (value >= 0), value, jnp.zeros((), brdf.dtype))


class MERLMaterial(eqx.Module):
    """A MERL-binned BRDF as a material: ``material(wi, wv)`` is the ABRDF (BRDF · cos θi).

    Nearest-bin lookup (:func:`merl_lookup`), 0 below the horizon and in bins without data. It
    can be sampled like the built-in materials (``abrdf_jax.sample(MERLMaterial(brdf), ...)``,
    ``abrdf-jax sample FILE.binary``).

    Attributes:
        brdf: shape ``(90, 90, 180, 3)``, physical units, as returned by :func:`read_merl_binary`.
    """

    brdf: Float[Array, "90 90 180 3"] = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        if self.brdf.shape != MERL_SHAPE:
            raise InputError(
                f"MERLMaterial: brdf has shape {self.brdf.shape}, expected {MERL_SHAPE}"
            )

    def __call__(
        self, wi: Float[Array, "... 3"], wv: Float[Array, "... 3"]
    ) -> Float[Array, "... 3"]:
        """ABRDF values ``(..., 3)`` at unit illumination and view vectors (z = surface normal)."""
        value = merl_lookup(self.brdf, wi, wv)
        cos_i = jnp.maximum(jnp.asarray(wi)[..., 2], 0.0).astype(value.dtype)
        return value * cos_i[..., None]
