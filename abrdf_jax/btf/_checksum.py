"""The checksum in a ``.npy`` chunk store's completion markers.

A marker written by this version carries ``crc32c``: the CRC-32C (Castagnoli) of the chunk's
whole ``.npy`` file, computed by the ``crc32c`` package with the processor's CRC instruction
(SSE 4.2 on x86-64, ARMv8 CRC on arm64) and the interpreter lock released: 2.5 ms for a
1,024-texel float16 chunk (40 MB), against 9.6 ms for zlib's CRC-32 in the same run
(``python -m benchmarks.btf``, 2026-12-07 07:00; docs/btf.md), which had been the largest part
of the BTF writers' processor time beside the compute. CRC-32C is what zarr's ``crc32c`` codec, iSCSI and
ext4's metadata use; it detects every burst error of up to 32 bits and every odd number of flipped
bits, as CRC-32 does.

Markers written before 2026-12-07 carry ``crc32`` (zlib's CRC-32); they are still verified with
it, so older stores resume and read as before.
"""

from __future__ import annotations

import zlib

import crc32c as _crc32c

#: Marker key → incremental checksum ``f(data, value) -> int`` (both start at 0).
CHECKSUMS = {"crc32c": _crc32c.crc32c, "crc32": zlib.crc32}
#: The algorithm of the markers this version writes.
CHECKSUM = "crc32c"


def checksum(*parts) -> dict:
    """``{CHECKSUM: value}``: the checksum of the bytes ``parts`` (buffers) concatenated."""
    fn, value = CHECKSUMS[CHECKSUM], 0
    for part in parts:
        value = fn(part, value)
    return {CHECKSUM: value}


def matches(marker: dict, data) -> bool:
    """Whether the bytes ``data`` agree with the checksum in ``marker`` (the first algorithm of
    :data:`CHECKSUMS` it carries); ``False`` when it carries none."""
    for key, fn in CHECKSUMS.items():
        if key in marker:
            return fn(data, 0) == marker[key]
    return False
