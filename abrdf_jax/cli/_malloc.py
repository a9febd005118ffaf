"""Freed large blocks kept for reuse by the C allocator (glibc), so that a command's large numpy
temporaries do not cost fresh pages on every call.

glibc's ``malloc`` serves a block of at least ``M_MMAP_THRESHOLD`` (128 KiB at start, raised
by its own rule up to 32 MiB as such blocks are freed) with its own ``mmap``, and gives memory at
the top of the main heap back to the system above ``M_TRIM_THRESHOLD``: in the main thread a loop
that allocates and frees a few megabytes of numpy temporaries can fault every page in again on
every pass (tests/test_cli_malloc.py's loop, two arrays of 1.6 MiB a pass in a fresh
interpreter, run by hand: 784 minor page faults a pass; 2.6 with the thresholds below). Whether it does depends on the heap's
history: a folder read by forked reader processes (:mod:`abrdf_jax.cli._readers`) left the
command's process in that state for the whole run. A scratch measurement on a folder of 200
jittered iso102 files (each its own layout, one small model per file; ``/usr/bin/time``, warm
caches): 1.24 million minor page faults and 4.9 s, against 24 thousand and 3.0 s with the
thresholds set (docs/notes.md).

:func:`keep_freed_blocks` sets both thresholds to the values glibc's own rule would reach at its
maximum (``mallopt``), once per command, unless the user set them (``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_``). Elsewhere (another C library, another system) it does nothing.

A command whose largest repeated block is larger raises both (``largest``): ``btf reconstruct``
allocates each chunk's output anew (1,024 texels: 40 MB in float16, 81 MB in float32), above
glibc's ceiling, so every chunk faulted its ~10,000 pages in again (scratch, docs/notes.md: the
command on the 256² benchmark's store, empty caches, two interleaved pairs: 10.7 and 9.8 s →
8.5 and 9.1 s, 710,000 → 370,000 minor faults, peak resident memory 0.64 → 0.78–0.84 GB: the
results waiting for the writers are kept blocks now).
"""

from __future__ import annotations

import os
import sys

#: glibc's ``mallopt`` parameters (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
#: Blocks below this size come from the heap (glibc's ceiling of its dynamic threshold).
MMAP_THRESHOLD = 32 * 2**20
#: Free memory at the top of the heap kept up to this size (twice the above, as glibc's rule).
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD
#: The most ``largest`` raises the mmap threshold to (larger blocks are mapped and unmapped each
#: time: their first touch is small next to their use).
MAX_THRESHOLD = 512 * 2**20
#: The environment variables by which a user sets the thresholds (they win).
USER_ENV = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def keep_freed_blocks(largest: int = 0) -> bool:
    """Set glibc's mmap and trim thresholds (module docstring); ``True`` when they were set.

    Args:
        largest: bytes of the largest block the command allocates again and again: the mmap
            threshold is raised above it (to whole MiB; the trim threshold twice that).
    """
    if not sys.platform.startswith("linux") or any(k in os.environ for k in USER_ENV):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # glibc only: another C library's mallopt may differ
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    above = (int(largest) // 2**20 + 1) * 2**20 if largest > 0 else 0
    mmap = min(max(MMAP_THRESHOLD, above), MAX_THRESHOLD)
    trim = max(TRIM_THRESHOLD, 2 * mmap)
    return mallopt(M_MMAP_THRESHOLD, mmap) == 1 and mallopt(M_TRIM_THRESHOLD, trim) == 1
