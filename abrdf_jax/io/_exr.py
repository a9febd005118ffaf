"""The one OpenEXR codec of the package: RGB float images in and out.

ABRDF tables (:mod:`abrdf_jax.io._tables`, one 81×81 image) and BTFs as one image per direction
pair (:mod:`abrdf_jax.btf._exr`) both read and write through these two functions, so a corrupt
or truncated file reads as the same :class:`InputError` everywhere. Needs OpenEXR ≥ 3.5 (its
``File.write`` takes an open file, which the atomic writes use).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._errors import InputError, located, require
from ._atomic import atomic_write
from ._untrusted import check_size


def _openexr():
    return require("OpenEXR", "reading or writing .exr", "OpenEXR>=3.5")


def read_rgb_exr(
    path, shape: tuple[int, int] | None = None, *, name: str | None = None
) -> np.ndarray:
    """The ``R``, ``G``, ``B`` channels of a single-part float EXR image as ``(H, W, 3)`` float32.

    Args:
        path: the image (other channels, e.g. ``A``, are ignored): a file, or a binary stream
            with ``read``/``seek``/``tell`` (e.g. a zip member's bytes in ``io.BytesIO``).
        shape: the expected ``(H, W)``, checked when given.
        name: what the messages call the image (default: ``path``).

    Raises:
        InputError naming the file: unreadable, truncated or corrupt, several parts, a missing
        channel, integer pixels, or the wrong size.
    """
    OpenEXR = _openexr()
    stream = hasattr(path, "read")
    source = path if stream else str(path)
    path = name or (path if stream else Path(path))
    _check_declared_size(OpenEXR, source, path, shape)
    if stream:
        source.seek(0)
    try:
        parts = OpenEXR.File(source, separate_channels=True).parts
    except Exception as e:  # noqa: BLE001 - the library raises RuntimeError, IndexError, ...
        raise located(f"cannot read as OpenEXR (truncated or corrupt?): {e}", path) from e
    if len(parts) == 0:  # OpenEXR 3.x returns no parts when the pixels cannot be decoded
        raise located(
            "cannot read as OpenEXR: no readable image part (truncated or corrupt?)", path
        )
    if len(parts) > 1:
        raise located(f"multi-part EXR ({len(parts)} parts); expected one RGB image", path)
    channels = parts[0].channels
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise located(
            f"EXR lacks channel(s) {', '.join(missing)}; it has {', '.join(sorted(channels)) or 'none'}",
            path,
        )
    planes = []
    for c in "RGB":
        px = np.asarray(channels[c].pixels)
        if px.dtype not in (np.float32, np.float16):
            raise located(
                f"EXR channel {c} has pixel type {px.dtype}, expected float or half", path
            )
        if shape is not None and px.shape != tuple(shape):
            got = f"{px.shape[1]}x{px.shape[0]}" if px.ndim == 2 else str(px.shape)
            raise located(
                f"EXR image is {got} (width x height), expected {shape[1]}x{shape[0]}", path
            )
        planes.append(px.astype(np.float32))
    return np.stack(planes, axis=-1)


def _check_declared_size(OpenEXR, source, path, shape) -> None:
    """Read the header only and refuse an image whose declared pixels exceed the size budget
    (or, with ``shape``, are not that size) before the library allocates them."""
    try:
        parts = OpenEXR.File(source, header_only=True).parts
    except Exception:  # noqa: BLE001 - reported by the full read, with the library's reason
        return
    for part in parts:
        header = part.header
        try:
            (x0, y0), (x1, y1) = (np.asarray(c, np.int64) for c in header["dataWindow"])
            channels = len(header.get("channels", ())) or 1
        except (KeyError, TypeError, ValueError):
            return  # no usable window: the full read reports it
        w, h = int(x1 - x0 + 1), int(y1 - y0 + 1)
        if w < 1 or h < 1:
            raise located(f"EXR header declares an empty data window ({w}x{h})", path)
        if shape is not None and (h, w) != tuple(shape):
            raise located(
                f"EXR image is {w}x{h} (width x height), expected {shape[1]}x{shape[0]}", path
            )
        check_size(w * h * max(channels, 3) * 4, f"EXR image {w}x{h}", path)


def write_rgb_exr(
    path: str | os.PathLike,
    rgb,
    *,
    half: bool = False,
    compression: str = "zip",
    comment: str | None = None,
    durable: bool = True,
) -> None:
    """Write ``(H, W, 3)`` values as an RGB EXR image, atomically.

    Args:
        half: 16-bit float channels (else 32-bit, which reads back bit for bit).
        compression: ``"zip"`` (lossless) or ``"none"``.
        comment: stored in the header.
        durable: as :func:`atomic_write`.
    """
    OpenEXR = _openexr()
    comp = {"zip": OpenEXR.ZIP_COMPRESSION, "none": OpenEXR.NO_COMPRESSION}[compression]
    header = {"compression": comp, "type": OpenEXR.scanlineimage}
    if comment:
        header["comment"] = comment
    dt = np.float16 if half else np.float32
    rgb = np.asarray(rgb)
    image = OpenEXR.File(
        header, {c: np.ascontiguousarray(rgb[..., k], dtype=dt) for k, c in enumerate("RGB")}
    )
    with atomic_write(path, "wb", durable=durable) as f:
        try:
            image.write(f)
        except (OSError, InputError):
            raise
        except Exception as e:  # noqa: BLE001 - the library raises RuntimeError and others
            raise InputError(f"cannot write {path}: OpenEXR: {e}") from e
