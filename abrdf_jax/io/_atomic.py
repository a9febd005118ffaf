"""Atomic file writes and the checks every reader makes before opening a file.

A writer that goes through :func:`atomic_write` either produces the complete file or leaves the
destination as it was: the data go to a temporary file in the same folder, which is flushed,
``fsync``-ed and then renamed over the destination (atomic on POSIX and Windows).

Temporary files are named ``.NAME.PID.XXXXXXXX.tmp`` beside ``NAME`` (PID: the writing process;
:func:`is_temp`, :func:`temp_owner`). A process killed mid-write leaves one behind; the next
writer of the same output removes those whose process is gone (:func:`remove_stale_temps`, run
by :func:`abrdf_jax.io._lock.output_lock` when it takes an output's lock), and every reader
ignores them (no real output starts with ``.`` and ends with ``.tmp``).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import itertools
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from .._errors import InputError, located

#: The suffix of every temporary file of :func:`atomic_write` (its prefix: ``.NAME.PID.``).
TEMP_SUFFIX = ".tmp"


@contextlib.contextmanager
def atomic_write(
    path: str | os.PathLike,
    mode: str = "wb",
    *,
    newline: str | None = None,
    durable: bool = True,
    drop_cache: bool = False,
) -> Iterator[IO]:
    """Open a temporary file beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary file lives in the same folder (so the final ``os.replace`` is atomic on POSIX
    and Windows), is flushed and ``fsync``-ed before the rename, and gets the permissions an
    ordinary new file would get (``0o666`` less the umask). If the block raises, the temporary
    file is removed, ``path`` is left untouched and the exception propagates.

    Args:
        path: the destination file (str or path-like).
        mode: ``"wb"`` (default) for bytes, ``"w"`` or ``"wt"`` for UTF-8 text.
        newline: passed to :func:`open` in text mode (``""`` to write ``"\\n"`` untranslated).
        durable: flush and ``fsync`` the file and its folder; ``False`` only renames (for
            thousands of files whose completion another file marks, as the BTF export's
            ``pairs.json``).
        drop_cache: with ``durable``, tell the kernel after the ``fsync`` that the file's pages
            are not needed again soon (``posix_fadvise(DONTNEED)`` where the platform has it):
            for large streamed outputs (BTF chunks), whose pages are written back already and
            would otherwise fill the page cache and cost the writer the kernel's work of finding
            fresh pages for the next chunk (``python -m benchmarks.btf``'s write stage).

    Yields:
        The open temporary file object.

    Raises:
        InputError: the folder does not exist or is not writable, ``path`` is a folder, writing
            fails with an ``OSError`` (disk full, I/O error), or the rename fails.
        ValueError: ``mode`` is not a write mode.
    """
    if mode not in ("wb", "w", "wt"):
        raise ValueError(f"atomic_write mode must be 'wb', 'w' or 'wt', got {mode!r}")
    path = Path(path)
    fd, tmp = _checked_temp(path, path.parent, lambda: _create_temp(path))
    try:
        kw = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        f = os.fdopen(fd, "wb" if "b" in mode else "w", **kw)
        try:
            with f:
                yield f
                if durable:
                    f.flush()
                    os.fsync(f.fileno())
                    if drop_cache:
                        _drop_cache(f.fileno())
        except OSError as e:  # disk full, I/O error: name the file (the temp file is removed below)
            raise write_error(path, e) from e
        try:
            os.replace(tmp, path)
        except OSError as e:
            raise write_error(path, e) from e
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if durable:
        _fsync_folder(path.parent)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """:func:`atomic_write` of one bytes object with ``durable=False`` (renamed into place, no
    ``fsync``), the same checks, errors and temporary files, in system calls on descriptors:
    no Python file object and no path objects (a folder run writes thousands of tables: the
    context manager cost 50 µs of Python each, under the interpreter lock its writer threads
    share with the computation; docs/notes.md, thirtieth session).

    Raises:
        InputError: as :func:`atomic_write`.
    """
    path = os.fspath(path)
    folder = os.path.dirname(path) or "."
    prefix = os.path.join(folder, f".{os.path.basename(path)}.{os.getpid()}.")
    fd, tmp = _checked_temp(path, folder, lambda: _open_temp(prefix))
    try:
        try:
            _write_all(fd, data)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as e:  # disk full, I/O error, the rename: name the file, not the temporary
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise write_error(path, e) from e
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _checked_temp(path, folder, create) -> tuple[int, str]:
    """The checks of every atomic write (the folder exists, ``path`` is not a folder), then its
    temporary file ``create()`` (``(descriptor, name)``); an :class:`InputError` naming
    ``path`` otherwise (one copy of the messages: :func:`atomic_write`,
    :func:`atomic_write_bytes`)."""
    if not os.path.isdir(folder):
        raise InputError(f"cannot write {path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise InputError(f"cannot write {path}: it is a folder")
    try:
        return create()
    except OSError as e:
        raise InputError(
            f"cannot write {path}: folder {folder} is not writable ({write_cause(e)})"
        ) from e


def _write_all(fd: int, data: bytes) -> None:
    """Write all of ``data`` to the descriptor ``fd`` (a write may take part of it)."""
    view, done = memoryview(data), 0
    while done < len(view):
        done += os.write(fd, view[done:])


def _drop_cache(fd: int) -> None:
    """Advise the kernel to drop the (clean, just ``fsync``-ed) pages of ``fd``; a no-op where
    the platform lacks ``posix_fadvise`` or refuses (advice only)."""
    advise = getattr(os, "posix_fadvise", None)
    if advise is not None:
        with contextlib.suppress(OSError):
            advise(fd, 0, 0, os.POSIX_FADV_DONTNEED)


#: The counter of the temporary files' names (``next`` is atomic in CPython).
_NAMES = itertools.count()
_TEMP_FLAGS = (
    os.O_WRONLY | os.O_CREAT | os.O_EXCL
    | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
)  # fmt: skip


def _create_temp(path: Path) -> tuple[int, str]:
    """A new temporary file beside ``path``, ``.NAME.PID.XXXXXXXX.tmp`` (a counter; ``O_EXCL``,
    so a killed writer's file whose pid came back is skipped), created with mode ``0o666``
    less the umask: the permissions of an ordinary new file, in one system call (a folder run
    writes thousands: ``mkstemp``'s random names and an ``fchmod`` cost more than the write)."""
    return _open_temp(str(path.parent / temp_prefix(path)))


def _open_temp(prefix: str) -> tuple[int, str]:
    """:func:`_create_temp` of a name prefix (``FOLDER/.NAME.PID.``)."""
    while True:
        tmp = f"{prefix}{next(_NAMES):08x}{TEMP_SUFFIX}"
        try:
            return os.open(tmp, _TEMP_FLAGS, 0o666), tmp
        except FileExistsError:
            continue


#: What a failed write means, beside the system's message, by ``errno``.
WRITE_HINTS = {
    errno.ENOSPC: "disk full",
    errno.EFBIG: "over the file-size limit: ulimit -f, or the file system's largest file",
    errno.EDQUOT: "over the disk quota",
    errno.EROFS: "mounted read-only",
}


def write_cause(e: BaseException) -> str:
    """The cause of a failed write: the system's message, and what it means
    (:data:`WRITE_HINTS`), e.g. ``File too large (over the file-size limit: ...)``."""
    if isinstance(e, InputError) and isinstance(e.__cause__, OSError):
        e = e.__cause__
    text = getattr(e, "strerror", None) or str(e) or type(e).__name__
    hint = WRITE_HINTS.get(getattr(e, "errno", None))
    return f"{text} ({hint})" if hint else text


def write_error(path, e: BaseException) -> InputError:
    """``cannot write PATH: CAUSE``: one line naming the output (not a temporary file) and why."""
    return InputError(f"cannot write {path}: {write_cause(e)}")


def write_figure(fig, path, **savefig) -> Path:
    """Save a matplotlib figure to ``path`` atomically (format from the suffix): rendered in
    memory, then :func:`atomic_write`, so a failed write leaves no partial image."""
    import io as _io

    path = Path(path)
    buf = _io.BytesIO()
    fig.savefig(buf, format=path.suffix.lower().lstrip("."), **savefig)
    with atomic_write(path, "wb") as f:
        f.write(buf.getvalue())
    return path


def temp_prefix(path: Path) -> str:
    """The name prefix of this process's temporary files for ``path`` (``.NAME.PID.``)."""
    return f".{Path(path).name}.{os.getpid()}."


def is_temp(name: str) -> bool:
    """Whether a file name is one of :func:`atomic_write`'s temporary files (``.*.tmp``)."""
    return name.startswith(".") and name.endswith(TEMP_SUFFIX) and len(name) > 5


def temp_owner(name: str) -> int | None:
    """The pid in a temporary file's name (``.NAME.PID.XXXXXXXX.tmp``); ``None`` if it has none."""
    if not is_temp(name):
        return None
    parts = name[: -len(TEMP_SUFFIX)].split(".")
    return int(parts[-2]) if len(parts) >= 4 and parts[-2].isdigit() else None


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this host (a process of another user counts)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def remove_stale_temps(
    path: str | os.PathLike, *, inside: bool = True, locked: bool = False
) -> int:
    """Remove the temporary files that killed writers of ``path`` left behind; returns how many.

    Those beside ``path`` (``.NAME.*.tmp``) and, when ``path`` is a folder and ``inside``, every
    temporary file under it, whose owner (the pid in its name) no longer runs, or that carries no
    pid (an older release's). ``locked``: the caller holds the output's lock
    (:func:`abrdf_jax.io._lock.output_lock`), so no other writer of ``path`` runs and every
    temporary file but this process's own is stale (its pid may have been reused). Errors (a
    file already gone, a read-only folder) are skipped.
    """
    path = Path(path)
    me, removed = os.getpid(), 0
    candidates: list[Path] = []
    with contextlib.suppress(OSError):
        candidates += [
            e for e in path.parent.glob(f".{glob_escape(path.name)}.*{TEMP_SUFFIX}") if e.is_file()
        ]
    if inside and path.is_dir():
        for root, _, names in os.walk(path):
            candidates += [Path(root) / n for n in names if is_temp(n)]
    for f in candidates:
        owner = temp_owner(f.name)
        if owner == me or (not locked and owner is not None and pid_alive(owner)):
            continue
        with contextlib.suppress(OSError):
            f.unlink()
            removed += 1
    return removed


def glob_escape(name: str) -> str:
    """``name`` with the glob wildcards ``*?[`` escaped."""
    import glob

    return glob.escape(name)


def _fsync_folder(folder: Path) -> None:
    # Make the rename itself durable; not possible (nor needed) on every platform.
    with contextlib.suppress(OSError):
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def _check_readable(path: Path) -> None:
    """Raise an InputError naming ``path`` if it is missing, a folder or cannot be opened.

    Opening it here means a permission problem is reported as such, not as whatever a
    format library (OpenEXR, zipfile) makes of it.
    """
    if not path.exists():
        raise located("file not found", path)
    if path.is_dir():
        raise located("is a folder, not a file", path)
    try:
        with open(path, "rb"):
            pass
    except OSError as e:
        raise located(f"cannot read: {e.strerror or e}", path) from e


def file_sha256(path) -> str:
    """sha256 (hex) of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
