"""A folder's inputs read and planned by worker processes (issue 13, the 1000-file folder).

Reading a measurement CSV file is numpy's C parser on some hundred rows (~0.2 ms for an iso102
file, ~0.4 ms for aniso204), then grouping it into slices (~0.1 ms): Python holding the GIL, so
threads cannot share it out, and before any table is written every input must be read and
checked (a bad file fails the run before work). On a folder of a thousand files that is half
of a warm call, on one core of several. Forked worker processes (one per core, at most
:data:`MAX_READERS`) read and plan the files in chunks; the parent takes the results in file
order, so the items, the errors and the console lines are those of a serial read: each file's
warnings are captured in its worker and printed by the parent in file order.

Used only where forking is safe and pays: at least :data:`PARALLEL_MIN` files, a ``fork`` start
method (Linux, macOS), no thread running in the parent and JAX not imported (JAX is
multithreaded; a command-line call that needs it imports it after the inputs are read), and no
file large enough to be announced before it is read (:data:`abrdf_jax.cli._progress.BIG_FILE_BYTES`).
``ABRDF_JAX_READERS=N`` sets the number of reader processes whatever the folder's size (``1``:
read in the calling process).
"""

from __future__ import annotations

import os
import sys
import threading

from .._errors import InputError
from ._progress import BIG_FILE_BYTES

#: Folders of fewer files are read in the calling process (a worker's start costs ~10 ms).
PARALLEL_MIN = 64
#: At most this many reader processes.
MAX_READERS = 8
#: The environment variable that sets the number of reader processes.
READERS_ENV = "ABRDF_JAX_READERS"


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _fork_is_safe() -> bool:
    import multiprocessing

    return (
        "fork" in multiprocessing.get_all_start_methods()
        and threading.active_count() == 1
        and "jax" not in sys.modules
    )


def reader_count(files) -> int:
    """How many processes read ``files`` (1: the calling process; module docstring).

    Raises:
        InputError: :data:`READERS_ENV` is set to something other than a whole number >= 1.
    """
    text = os.environ.get(READERS_ENV, "").strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if n < 1:
            raise InputError(
                f"{READERS_ENV}={text!r}: expected a whole number of reader processes (1 or more)"
            )
    else:
        if len(files) < PARALLEL_MIN:
            return 1
        n = min(_cores(), MAX_READERS)
    if n < 2 or len(files) < 2 or not _fork_is_safe():
        return 1
    try:
        if any(os.path.getsize(f) >= BIG_FILE_BYTES for f in files):
            return 1  # announced before it is read: the serial reader does that
    except OSError:
        return 1  # the serial reader names the missing or unreadable file
    return min(n, len(files))


def read_parallel(work, jobs: list, n: int, make_bar) -> list:
    """``[work(job) for job in jobs]`` by ``n`` forked processes, in order (``work``: a
    module-level function, as pickle names it; its results are pickled back). ``make_bar()``
    makes the progress bar, after the workers are forked (a bar may start a thread)."""
    import multiprocessing

    chunk = max(1, min(64, len(jobs) // (4 * n)))
    with multiprocessing.get_context("fork").Pool(n) as pool:
        results = pool.imap(work, jobs, chunksize=chunk)
        with make_bar() as bar:
            out = []
            for r in results:
                out.append(r)
                bar.update(1)
    return out
