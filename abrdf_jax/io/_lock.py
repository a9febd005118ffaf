"""One writer per output: a lock file beside it holding the holder's pid and host.

:func:`output_lock` guards an output (a file, an output folder or a chunked store) for the time
a command writes it. The lock is the file ``.NAME.lock`` beside the output, created if needed
and locked with ``flock`` (POSIX; the kernel drops the lock when its process dies, however it
dies); the holder writes its pid, host and start time into it and removes it on release. A
second process asking for the same output is refused at once with an :class:`InputError` naming
the holder. A lock file whose holder was killed (``flock`` free, the pid no longer running) is
taken over with a warning, and the temporary files the killed writer left are removed
(:func:`abrdf_jax.io._atomic.remove_stale_temps`). Without ``fcntl`` (Windows) the file is
created exclusively instead (``O_EXCL``) and a holder whose pid is gone on this host counts as
stale.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from .._errors import InputError
from ._atomic import pid_alive, remove_stale_temps, write_cause

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

LOCK_SUFFIX = ".lock"
#: The file descriptors of the locks this process holds (:func:`held_lock_fds`).
_HELD: set[int] = set()
#: Reads of a locked but still empty lock file (10 ms apart) before the refusal names no holder.
HOLDER_READS = 20


def lock_path(output: str | os.PathLike) -> Path:
    """The lock file of ``output``: ``.NAME.lock`` in the same folder."""
    output = Path(output)
    return output.parent / f".{output.name}{LOCK_SUFFIX}"


def _holder(text: str) -> dict:
    try:
        d = json.loads(text)
    except ValueError:
        return {}
    return d if isinstance(d, dict) else {}


def _describe(holder: dict) -> str:
    if not holder:
        return "another process"
    since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(holder.get("time", 0)))
    return f"process {holder.get('pid')} on host {holder.get('host')} (since {since})"


def _cannot(output, lock: Path, e: OSError) -> InputError:
    return InputError(f"cannot write {output}: {write_cause(e)} (at its lock file {lock.name})")


@contextlib.contextmanager
def output_lock(
    output: str | os.PathLike,
    warn: Callable[[str], None] | None = None,
    also: tuple | list = (),
) -> Iterator[Path]:
    """Hold the lock of ``output`` for the block; yields the lock file's path.

    On entry the temporary files of killed writers of ``output`` are removed (beside it and,
    for a folder, inside it).

    Args:
        output: the file or folder about to be written (its folder must exist).
        warn: called with one message when a stale lock (a killed holder) is taken over
            (default: :func:`warnings.warn`).
        also: files written beside ``output`` under the same lock (a model record): their
            killed writers' temporary files are removed too.

    Raises:
        InputError: another live process holds the lock (the message names its pid and host and
            the lock file), or the lock file cannot be created (read-only folder, disk full).
    """
    lock = lock_path(output)
    if fcntl is None:
        fd, old = _acquire_exclusive(lock, output)
    else:
        fd, old = _acquire_flock(lock, output)
    _HELD.add(fd)
    try:
        if old and old.get("pid") != os.getpid():
            message = (
                f"{output}: took over the lock {lock} of {_describe(old)}, which ended without "
                "releasing it (killed?)"
            )
            if warn is None:
                import warnings

                warnings.warn(message, RuntimeWarning, stacklevel=3)
            else:
                warn(message)
        me = {"pid": os.getpid(), "host": socket.gethostname(), "time": time.time()}
        try:
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, json.dumps(me).encode())
        except OSError as e:
            raise _cannot(output, lock, e) from e
        for path in (output, *also):
            remove_stale_temps(path, locked=True)
        yield lock
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()  # while still locked: a waiting process then finds a new file
        _HELD.discard(fd)
        os.close(fd)


def held_lock_fds() -> frozenset[int]:
    """The file descriptors of the output locks this process holds. A forked child inherits
    them, and a ``flock`` is released only when every descriptor of it is closed: a child
    that outlives its parent would keep the output locked. A forked worker closes them first
    (:mod:`abrdf_jax.cli._readers`)."""
    return frozenset(_HELD)


def _refuse(output, lock: Path, holder: dict) -> InputError:
    return InputError(
        f"{output}: is being written by {_describe(holder)}; lock file {lock}. Wait for it to "
        "finish (or remove the lock file if that process is gone)"
    )


def _read(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    chunks = []
    while block := os.read(fd, 4096):
        chunks.append(block)
    return b"".join(chunks).decode("utf-8", "replace")


def _acquire_flock(lock: Path, output) -> tuple[int, dict]:
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise _cannot(output, lock, e) from e
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder(_read(fd))
            # The holder writes its pid just after taking the lock: read again for a moment so
            # the refusal can name it (a run started alongside it may see the file still empty)
            for _ in range(HOLDER_READS):
                if holder:
                    break
                time.sleep(0.01)
                holder = _holder(_read(fd))
            os.close(fd)
            raise _refuse(output, lock, holder) from None
        # The holder before us may have removed the file after we opened it: then this lock
        # guards nothing, and another process may already hold a new file's lock. Retry.
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd, _holder(_read(fd))
        os.close(fd)


def _acquire_exclusive(lock: Path, output) -> tuple[int, dict]:
    for _ in range(2):
        try:
            return os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), {}
        except FileExistsError:
            try:
                holder = _holder(lock.read_text(encoding="utf-8"))
            except OSError:
                holder = {}
            pid = holder.get("pid")
            here = holder.get("host") == socket.gethostname()
            if not (here and isinstance(pid, int) and not pid_alive(pid)):
                raise _refuse(output, lock, holder) from None
            with contextlib.suppress(OSError):
                lock.unlink()
        except OSError as e:
            raise _cannot(output, lock, e) from e
    raise _refuse(output, lock, {})
