"""The images of a BTF capture: PNG, JPEG and OpenEXR files, in a folder or a zip archive.

A device or a BTF database gives one image per (light, view) direction pair
(:mod:`abrdf_jax.btf._exr` names and orders them). This module decodes one such image to linear
RGB ``(H, W, 3)`` float32, by suffix (case-insensitive, :data:`DECODERS`):

- ``.png``, ``.jpg``, ``.jpeg``: sRGB code values ``k`` of 8 bits (or 16 bits, PNG only) scaled
  to ``k / (2^bits − 1)`` and decoded to linear with the IEC 61966-2-1 curve
  (:func:`abrdf_jax.metrics.srgb_decode`, through a lookup table of every code value). Pillow
  decodes them, except 16-bit PNGs: Pillow reads those as their high 8 bits, so a small decoder
  here (zlib and the five PNG row filters) keeps all 16. Grey images are repeated to RGB, alpha
  is dropped; gAMA/iCCP chunks are not read (the values are taken as sRGB).
- ``.exr``: linear values as they are (:func:`abrdf_jax.io._exr.read_rgb_exr`, half or float),
  refused when they hold NaN or infinity.

:func:`open_source` lists and reads the files of a folder (recursively: the UTIA database keeps
each view's images in a sub-folder ``tv000_pv000/``) or the members of a zip archive (the
UBO2003 downloads; possibly in a sub-folder inside the zip), one file at a time and without
extracting anything to disk. Every error names the file (``ZIP:member`` inside a zip).
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._errors import InputError, located, require
from ..io._exr import read_rgb_exr
from ..io._untrusted import check_archive, check_size, read_member

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour type -> channels (grey, RGB, grey + alpha, RGBA); 3 (palette) is never 16-bit
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}
# Pillow modes read as 8-bit code values (converted to RGB: grey repeated, palette looked up,
# alpha dropped); others (CMYK, 32-bit integer or float) are refused
_PILLOW_MODES = ("RGB", "RGBA", "L", "LA", "P", "PA", "1")
# bytes a pixel takes once decoded (float32 RGB): what the size budget bounds
_DECODED_BYTES = 12


@lru_cache(maxsize=None)
def srgb_table(bits: int) -> np.ndarray:
    """Linear value of every ``bits``-bit sRGB code value, ``(2^bits,)`` float32."""
    from ..metrics._color import srgb_decode

    codes = np.arange(2**bits, dtype=np.float64) / (2**bits - 1)
    return srgb_decode(codes, xp=np).astype(np.float32)  # float64, then rounded once


def _pillow():
    return require("PIL.Image", "reading PNG or JPEG images", "pillow>=10", "Pillow")


def _decode_pillow(data: bytes, name: str) -> tuple[np.ndarray, str]:
    """An 8-bit PNG or JPEG image: linear RGB and ``"8-bit sRGB"``."""
    Image = _pillow()
    try:
        with Image.open(io.BytesIO(data)) as im:  # reads the header only
            check_size(im.width * im.height * _DECODED_BYTES, "image (decoded)", name)
            if im.mode not in _PILLOW_MODES:
                raise located(
                    f"image mode {im.mode} is not supported; expected RGB, RGBA or grey", name
                )
            im.load()  # decode every pixel now: a truncated file fails here
            rgb = np.asarray(im if im.mode == "RGB" else im.convert("RGB"))
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - Pillow raises OSError, SyntaxError, ValueError, ...
        raise located(f"cannot read as an image (truncated or corrupt?): {e}", name) from e
    return srgb_table(8)[rgb], "8-bit sRGB"


def _unfilter_sequential(line: list, prev: list, bpp: int, paeth: bool) -> list:
    """PNG filter 3 (average) or 4 (Paeth) undone: each byte depends on the one ``bpp`` left."""
    out = [0] * len(line)
    for i, x in enumerate(line):
        a = out[i - bpp] if i >= bpp else 0
        b = prev[i]
        if paeth:
            c = prev[i - bpp] if i >= bpp else 0
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
        else:
            pred = (a + b) >> 1
        out[i] = (x + pred) & 255
    return out


def _unfilter(rows: np.ndarray, bpp: int, name: str) -> np.ndarray:
    """The raw bytes ``(H, stride)`` of filtered PNG rows ``(H, 1 + stride)`` (filter byte first)."""
    out = np.empty((rows.shape[0], rows.shape[1] - 1), np.uint8)
    prev = np.zeros(rows.shape[1] - 1, np.uint8)
    for r, row in enumerate(rows):
        kind, line = int(row[0]), row[1:]
        if kind == 0:  # none
            cur = line
        elif kind == 1:  # sub: a running sum (mod 256) of each byte of a pixel
            cur = np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).reshape(-1)
        elif kind == 2:  # up
            cur = line + prev
        elif kind in (3, 4):
            seq = _unfilter_sequential(line.tolist(), prev.tolist(), bpp, paeth=kind == 4)
            cur = np.array(seq, np.uint8)
        else:
            raise located(f"PNG row {r} has filter type {kind}; valid are 0 to 4 (corrupt?)", name)
        out[r] = prev = cur
    return out


def _decode_png16(data: bytes, name: str) -> tuple[np.ndarray, str]:
    """A 16-bit PNG (grey, grey + alpha, RGB or RGBA; not interlaced): linear RGB."""
    pos, header, idat = len(_PNG_SIGNATURE), None, []
    while True:
        if pos + 12 > len(data):
            raise located("PNG is truncated (no IEND chunk)", name)
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body, crc = data[pos + 8 : pos + 8 + n], data[pos + 8 + n : pos + 12 + n]
        if len(crc) < 4 or zlib.crc32(kind + body) != struct.unpack(">I", crc)[0]:
            raise located(f"PNG chunk {kind.decode('latin-1')!r} is truncated or corrupt", name)
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + n
    if header is None:
        raise located("PNG has no IHDR chunk (corrupt?)", name)
    w, h, _, colour, _, _, interlace = header
    channels = _PNG_CHANNELS.get(colour)
    if channels is None or interlace:
        what = "interlaced" if interlace else f"colour type {colour}"
        raise located(f"16-bit PNG, {what}, is not supported; save it non-interlaced", name)
    stride = w * channels * 2
    check_size(w * h * _DECODED_BYTES, "image (decoded)", name)  # before inflating anything
    try:  # inflate at most what the header declares (+1 byte to see a longer stream)
        raw = zlib.decompressobj().decompress(b"".join(idat), h * (stride + 1) + 1)
    except zlib.error as e:
        raise located(f"PNG pixel data is corrupt: {e}", name) from e
    if len(raw) != h * (stride + 1):
        raise located(f"PNG pixel data has {len(raw)} bytes, expected {h * (stride + 1)}", name)
    rows = np.frombuffer(raw, np.uint8).reshape(h, stride + 1)
    codes = _unfilter(rows, channels * 2, name).view(">u2").reshape(h, w, channels)
    rgb = codes[..., :3] if channels >= 3 else np.repeat(codes[..., :1], 3, axis=-1)
    return srgb_table(16)[rgb], "16-bit sRGB"


def _decode_png(data: bytes, name: str) -> tuple[np.ndarray, str]:
    # the bit depth is byte 24: signature (8), IHDR length and type (8), width and height (8)
    if data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR" and len(data) > 24 and data[24] == 16:
        return _decode_png16(data, name)
    return _decode_pillow(data, name)


def _decode_exr(data: bytes, name: str) -> tuple[np.ndarray, str]:
    rgb = read_rgb_exr(io.BytesIO(data), name=name)
    bad = ~np.isfinite(rgb)
    if bad.any():
        r, c, _ = np.argwhere(bad)[0]
        raise located(f"holds NaN or infinite values (first at row {r}, column {c})", name)
    return rgb, "linear EXR"


#: Image suffix (lower case) -> decoder ``(bytes, name) -> (linear RGB (H, W, 3), what)``.
DECODERS = {
    ".png": _decode_png,
    ".jpg": _decode_pillow,
    ".jpeg": _decode_pillow,
    ".exr": _decode_exr,
}
#: Suffix -> how its values are encoded (a capture may not mix the two: different scales).
ENCODINGS = {".png": "sRGB", ".jpg": "sRGB", ".jpeg": "sRGB", ".exr": "linear"}


def decode_image(data: bytes, name: str) -> tuple[np.ndarray, str]:
    """One image's bytes as linear RGB ``(H, W, 3)`` float32, and what it was (e.g. 8-bit sRGB).

    Raises:
        InputError naming ``name``: an unknown suffix, an unreadable, truncated or corrupt image,
        an unsupported mode, NaN or infinity in an EXR.
    """
    suffix = Path(name).suffix.lower()
    if suffix not in DECODERS:
        raise located(f"unknown image suffix {suffix!r}; expected one of {tuple(DECODERS)}", name)
    return DECODERS[suffix](data, name)


class Source:
    """A folder or a zip archive of images (:func:`open_source` makes one).

    ``names()`` lists its files (POSIX paths inside it), ``read(name)`` gives one file's bytes,
    ``label(name)`` what messages call it, ``image(name)`` the decoded image. Use it as a
    context manager: a zip archive stays open until the end of the block.
    """

    path: Path
    is_zip = False

    def image(self, name: str) -> tuple[np.ndarray, str]:
        """The image ``name`` decoded (:func:`decode_image`)."""
        return decode_image(self.read(name), self.label(name))

    def close(self) -> None:
        pass

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Folder(Source):
    """The files of a folder and its sub-folders."""

    def __init__(self, path: Path):
        self.path = path

    def names(self) -> list[str]:
        files = (p for p in self.path.rglob("*") if p.is_file())
        return sorted(p.relative_to(self.path).as_posix() for p in files)

    def label(self, name: str) -> str:
        return str(self.path / name)

    def read(self, name: str) -> bytes:
        try:
            check_size((self.path / name).stat().st_size, "file", self.label(name))
            return (self.path / name).read_bytes()
        except OSError as e:
            raise located(f"cannot read: {e.strerror or e}", self.label(name)) from e


class _Zip(Source):
    """The members of a zip archive, read one at a time into memory, never extracted."""

    is_zip = True

    def __init__(self, path: Path):
        self.path = path
        try:
            self.zf = zipfile.ZipFile(path)
        except (zipfile.BadZipFile, OSError) as e:
            raise located(f"cannot read as a zip archive: {e}", path) from e
        try:
            check_archive(self.zf, path)  # every member's name and declared size, up front
        except InputError:
            self.zf.close()
            raise

    def names(self) -> list[str]:
        return [i.filename for i in self.zf.infolist() if not i.is_dir()]

    def label(self, name: str) -> str:
        return f"{self.path}:{name}"

    def read(self, name: str) -> bytes:
        try:
            return read_member(self.zf, name, self.path)
        except (zipfile.BadZipFile, zlib.error, OSError, RuntimeError, NotImplementedError) as e:
            # BadZipFile: a CRC mismatch; RuntimeError: encrypted; NotImplementedError: method
            raise located(f"cannot read from the zip archive: {e}", self.label(name)) from e

    def close(self) -> None:
        self.zf.close()


def open_source(path) -> Source:
    """The folder or zip archive of images at ``path``.

    Raises:
        InputError: ``path`` does not exist, or is a file that is not a zip archive.
    """
    path = Path(path)
    if path.is_dir():
        return _Folder(path)
    if path.is_file() and zipfile.is_zipfile(path):
        return _Zip(path)
    if path.exists():
        raise InputError(f"{path}: neither a folder nor a zip archive of images")
    raise InputError(f"{path}: not found")
