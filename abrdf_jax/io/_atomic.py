"""Atomic file writes and the checks every reader makes before opening a file.

A writer that goes through :func:`atomic_write` either produces the complete file or leaves the
destination as it was: the data go to a temporary file in the same folder, which is flushed,
``fsync``-ed and then renamed over the destination (atomic on POSIX and Windows).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from .._errors import InputError, located


def _current_umask() -> int:
    # os.umask can only be read by setting it; restore it at once.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(
    path: str | os.PathLike, mode: str = "wb", *, newline: str | None = None, durable: bool = True
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
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"cannot write {path}: folder {folder} does not exist")
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a folder")
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise InputError(
            f"cannot write {path}: folder {folder} is not writable ({e.strerror})"
        ) from e
    try:
        # fchmod is POSIX only; mkstemp's 0o600 is still safe
        with contextlib.suppress(AttributeError, OSError):
            os.fchmod(fd, 0o666 & ~_current_umask())
        kw = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        f = os.fdopen(fd, "wb" if "b" in mode else "w", **kw)
        try:
            with f:
                yield f
                if durable:
                    f.flush()
                    os.fsync(f.fileno())
        except OSError as e:  # disk full, I/O error: name the file (the temp file is removed below)
            raise InputError(f"cannot write {path}: {e.strerror or e}") from e
        try:
            os.replace(tmp, path)
        except OSError as e:
            raise InputError(f"cannot write {path}: {e.strerror}") from e
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if durable:
        _fsync_folder(folder)


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
