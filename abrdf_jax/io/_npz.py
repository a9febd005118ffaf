"""One array as an uncompressed ``.npz`` archive, built in memory (issue 13: a folder's tables).

``numpy.savez`` spends most of a small table's write in Python (``zipfile``'s objects, the
``.npy`` header built per call): for the 79 kB tables of a folder run that is more than the
write itself. :func:`npz_bytes` builds the same archive directly: a zip with one stored
(uncompressed) member ``NAME.npy`` holding numpy's ``.npy`` format (header from
``numpy.lib.format``, made once per shape and dtype). ``numpy.load`` and
:func:`abrdf_jax.io.read_table` read it as they read ``numpy.savez``'s; the member's time stamp
is the zip epoch (1980-01-01), so equal arrays give equal bytes.
"""

from __future__ import annotations

import functools
import io
import struct
import zlib

import numpy as np

_LOCAL = struct.Struct("<IHHHHHIIIHH")  # local file header, then the name
_CENTRAL = struct.Struct("<IHHHHHHIIIHHHHHII")  # central directory header, then the name
_END = struct.Struct("<IHHHHIIH")  # end of central directory
_VERSION = 20  # zip 2.0: stored members, no zip64 (a table is far below 4 GiB)
_DATE = (1 << 5) | 1  # 1980-01-01, the zip epoch (time 00:00:00)
_MAX = 0xFFFFFFFF  # the largest member a zip without zip64 holds


@functools.lru_cache(maxsize=8)
def _npy_header(shape: tuple, dtype: str) -> bytes:
    """The ``.npy`` header numpy writes for a C-ordered array of ``shape`` and ``dtype``."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": dtype, "fortran_order": False, "shape": shape}
    )
    return buf.getvalue()


def npz_bytes(name: str, arr: np.ndarray) -> bytes:
    """The bytes of an ``.npz`` archive holding ``arr`` (C order) as the member ``name``."""
    arr = np.ascontiguousarray(arr)
    data = _npy_header(arr.shape, np.lib.format.dtype_to_descr(arr.dtype)) + arr.tobytes()
    if len(data) > _MAX:
        raise ValueError(f"an array of {len(data)} bytes needs zip64: use numpy.savez")
    member = (name + ".npy").encode()
    crc, n = zlib.crc32(data), len(data)
    local = _LOCAL.pack(0x04034B50, _VERSION, 0, 0, 0, _DATE, crc, n, n, len(member), 0)
    central = _CENTRAL.pack(
        0x02014B50, _VERSION, _VERSION, 0, 0, 0, _DATE, crc, n, n, len(member), 0, 0, 0, 0,
        0o644 << 16, 0,
    )  # fmt: skip
    head = local + member
    tail = central + member
    end = _END.pack(0x06054B50, 0, 0, 1, 1, len(tail), len(head) + n, 0)
    return b"".join((head, data, tail, end))
