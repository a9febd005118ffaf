"""One BLAS thread for ``abrdf-jax reconstruct``.

numpy's OpenBLAS (the library numpy's wheels ship) runs a matrix product on one thread per core,
and its worker threads spin on their core for a while (OpenBLAS's thread timeout) before they
sleep: after each product, and when they start (at numpy's import, after a fork at the next call
that asks for threads, and when the count is set). The command's products are small (a folder
batch's map product is about a GFLOP; one file's is a few MFLOP), one thread does them in
milliseconds, and the spinning took cores other work needed:

- a folder run computes each batch while a small thread pool writes the previous batch's tables
  (:mod:`abrdf_jax.cli.reconstruct`) and reads its inputs in forked reader processes
  (:mod:`abrdf_jax.cli._readers`): a scratch ``perf record`` of a 1000-file iso102 folder call
  (docs/notes.md) counted 14.6 % of the process's samples in OpenBLAS's idle loop
  (``blas_thread_server``) against 1.5 % in its matrix kernel, and each reader's worker spun at
  its first grouping;
- one file's call spent about as much CPU spinning as computing (scratch, warm iso102 file:
  0.25 s of user CPU, 0.12-0.15 s with one thread, the same 0.17 s of wall time), and several
  calls at once (a shell loop with ``xargs -P``, a job array) took each other's cores
  (``python -m benchmarks.cli``, the row of 40 files two at a time).

The price is a cold call's build of an operator in numpy (a solve and products of some thousand
rows, now on one core: scratch, one cold aniso204 ``--model auto`` file 0.71-0.75 s with two
threads on an idle machine, 0.75-0.84 s with one).

:func:`one_blas_thread` sets OpenBLAS to one thread for the block it guards and restores the
count after; the command enters it before numpy is imported, so that OpenBLAS starts without
worker threads (none spins at the import), and a folder's reader processes inherit that. Scratch
checks: importing numpy and sleeping cost 0.22 s of CPU, 0.08 s with ``OPENBLAS_NUM_THREADS=1``;
setting one thread in a freshly forked child cost it 0.1 s of CPU, setting it before the fork
nothing.

Nothing happens (it yields ``False``) where numpy's BLAS is not an OpenBLAS this module can find
(another BLAS, another system) or where the user chose the thread count
(``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``, ``GOTO_NUM_THREADS``). The thread count changes
how a product is split and blocked, not what it computes: a folder's tables agree with those of
a run on more threads within a few float32 units in the last place (a scratch comparison over
the 1000-file iso102 and aniso204 folders of ``python -m benchmarks.cli``: 4 at most;
tests/test_cli_blas.py allows 8; docs/stability.md, "Load").
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys

from ._readers import cores

#: The environment variables by which a user sets OpenBLAS's thread count (they win).
USER_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "GOTO_NUM_THREADS")
#: The one :func:`one_blas_thread` sets while numpy is not yet imported.
ENV = USER_ENV[0]
#: The names OpenBLAS's thread-count functions have in the builds numpy ships (scipy-openblas,
#: 64-bit integers, with its symbol suffix) and in a system's OpenBLAS.
_NAMES = (
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
    ("openblas_set_num_threads", "openblas_get_num_threads"),
)


def _loaded_openblas() -> list[str]:
    """The paths of the OpenBLAS libraries this process has loaded (Linux: its memory map)."""
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.lower()}
    except OSError:
        return []
    return sorted(p for p in paths if p.startswith(os.sep))


def _thread_functions():
    """``(set, get)`` of numpy's OpenBLAS, or ``None`` (numpy is imported first)."""
    import numpy  # noqa: F401 - loads the BLAS whose threads are set

    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)  # the library already loaded: the same handle
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            setter, getter = getattr(lib, set_name, None), getattr(lib, get_name, None)
            if setter is not None and getter is not None:
                setter.argtypes, setter.restype = (ctypes.c_int,), None
                getter.argtypes, getter.restype = (), ctypes.c_int
                return setter, getter
    return None


def set_threads(n: int) -> int | None:
    """Set OpenBLAS's thread count to ``n``; the count before, or ``None`` where nothing was set
    (no OpenBLAS found)."""
    found = _thread_functions()
    if found is None:
        return None
    setter, getter = found
    before = getter()
    setter(n)
    return max(1, before)


@contextlib.contextmanager
def one_blas_thread():
    """OpenBLAS on one thread inside the block (module docstring); yields whether it was set.

    Before numpy is imported (a command's own process) it sets :data:`ENV` to 1, so that
    OpenBLAS starts without workers (none spins, none is forked); after the block the variable
    is removed and, where numpy was imported inside it, the count set back to the cores'.
    With numpy imported the count is set and restored with OpenBLAS's own functions."""
    if any(k in os.environ for k in USER_ENV):
        yield False
        return
    if "numpy" not in sys.modules:
        os.environ[ENV] = "1"
        try:
            yield True
        finally:
            os.environ.pop(ENV, None)
            if "numpy" in sys.modules:
                set_threads(cores())
        return
    before = set_threads(1)
    try:
        yield before is not None
    finally:
        if before is not None:
            set_threads(before)
