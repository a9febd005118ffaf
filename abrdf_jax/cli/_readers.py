"""A folder's inputs read and planned: in this process (:func:`read_serial`) or, for a large
folder, by forked reader processes (:func:`read_parallel`; issue 13, the 1000-file folder).
Both run :func:`read_one` per file and :func:`merged` on the results.

Reading a measurement CSV file is numpy's C parser on some hundred rows, then grouping it into
slices: Python holding the GIL, so threads cannot share it out, and before any table is
written every input must be read and checked (a bad file fails the run before work). On a
folder of a thousand files that is a large part of a warm call (`python -m benchmarks.cli`
reports the parse alone on one core as a floor), on one core of several. Forked worker processes (one per core, at most
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

import contextlib
import io as _io
import os
import sys
import threading
import time

from .._errors import InputError
from ._progress import BIG_FILE_BYTES, BigFile

#: Folders of fewer files are read in the calling process (forking a worker costs more than
#: reading a few files).
PARALLEL_MIN = 64
#: At most this many reader processes.
MAX_READERS = 8
#: The environment variable that sets the number of reader processes.
READERS_ENV = "ABRDF_JAX_READERS"
#: What a reader imports to read and plan a file (numpy, the CSV reader, the grouping;
#: ``numpy.ma``, which ``numpy.median`` imports on its first call):
#: imported by the parent before it forks, so that the readers inherit them. Each reader
#: imported them itself on its first file (0.07 s of each reader's time, all readers at once,
#: while the parent, which needs them later anyway, waited; docs/notes.md, 30th session).
PRELOAD = ("numpy", "numpy.ma", "abrdf_jax.io._csv", "abrdf_jax._grouping", "abrdf_jax._arrays")


def cores() -> int:
    """The cores this process may run on."""
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
        n = min(cores(), MAX_READERS)
    if n < 2 or len(files) < 2 or not _fork_is_safe():
        return 1
    try:
        if any(os.path.getsize(f) >= BIG_FILE_BYTES for f in files):
            return 1  # announced before it is read: the serial reader does that
    except OSError:
        return 1  # the serial reader names the missing or unreadable file
    return min(n, len(files))


def _orphan_guard(parent: int) -> None:
    """A reader's first act (the pool's initializer): close the output locks inherited from
    the parent (a ``flock`` held by a descriptor of a reader that outlives a killed parent
    would keep the output locked: ``abrdf_jax.io._lock.held_lock_fds``), and die with the
    parent (Linux: ``PR_SET_PDEATHSIG``; elsewhere a thread that watches the parent's pid)
    instead of waiting forever on the pool's queue."""
    from ..io._lock import held_lock_fds

    for fd in held_lock_fds():
        with contextlib.suppress(OSError):
            os.close(fd)
    try:
        import ctypes
        import signal

        armed = ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL) == 0  # PDEATHSIG
    except (OSError, AttributeError):
        armed = False
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)
    if not armed:

        def watch():
            while os.getppid() == parent:
                time.sleep(0.05)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()


def read_one(plan, values, forced, alpha, keep: bool, warn: bool, path) -> tuple[str, object, str]:
    """One input: ``(what, result, console text)``; ``what`` is ``"ok"`` (result: the planned
    item, or ``None`` when not kept), ``"read"`` or ``"plan"`` (result: the error's message).
    What the planning says on stderr is returned, for :func:`merged` to print in file order.
    ``plan`` and ``values``: the command line's ``_common.plan`` and ``_common.warn_values``
    (bound with :func:`functools.partial`, the one function both readers call)."""
    from .. import io

    out = _io.StringIO()
    with contextlib.redirect_stderr(out):
        try:
            samples = io.read_sample_columns(path)
        except InputError as e:
            return "read", str(e), ""
        try:
            item = plan(samples, forced, alpha, path, warn, noise=False)
        except InputError as e:
            return "plan", str(e), out.getvalue()
        if not keep and warn:
            values(path, samples)
    return "ok", item if keep else None, out.getvalue()


def read_serial(work, files, quiet: bool, make_bar) -> list:
    """``work(path)`` (a bound :func:`read_one`) of every file in this process, in order; a
    large file is announced before it is read."""
    out = []
    with make_bar() as bar:
        for f in files:
            with BigFile(f, quiet):
                out.append(work(f))
            bar.update(1)
    return out


def read_parallel(work, files, n: int, make_bar) -> list | None:
    """``work(path)`` (a bound :func:`read_one`) of every file by ``n`` forked readers, in
    order; ``None`` when a reader died (killed by the system, say: the caller reads in its own
    process instead). ``make_bar()`` makes the progress bar, after the readers are forked (a
    bar may start a thread)."""
    import importlib
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    for name in PRELOAD:  # inherited by the readers (PRELOAD)
        importlib.import_module(name)
    chunk = max(1, min(64, len(files) // (4 * n)))
    ctx = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(n, ctx, initializer=_orphan_guard, initargs=(os.getpid(),)) as pool:
        try:
            results = pool.map(work, files, chunksize=chunk)  # forks the readers
            with make_bar() as bar:
                out = []
                for r in results:
                    out.append(r)
                    bar.update(1)
        except BrokenProcessPool:
            return None
    return out


def merged(files, done: list, keep: bool, before) -> tuple[list, list]:
    """``(bad, items)`` of the readers' results ``done``, with the outcome and console lines of
    reading every file before planning any: when kept, a read error anywhere refuses the run
    with the read errors only (nothing planned is said), else ``before()``, the planning's
    lines in file order, then its errors; when only checked, each file's lines and error in
    file order, then ``before()`` if none failed."""
    unread = [(f, r) for f, (what, r, _) in zip(files, done) if what == "read"]
    if keep:
        if before is not None and not unread:
            before()  # after reading, before what planning says
        if not unread:
            sys.stderr.write("".join(text for _, _, text in done))
        bad = unread or [(f, r) for f, (what, r, _) in zip(files, done) if what == "plan"]
    else:
        sys.stderr.write("".join(text for _, _, text in done))
        bad = [(f, r) for f, (what, r, _) in zip(files, done) if what != "ok"]
        if before is not None and not bad:
            before()
    return bad, [r for what, r, _ in done if what == "ok" and r is not None]
