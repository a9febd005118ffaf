"""JAX's persistent compilation cache in the package's cache folder, written atomically (issue 13).

:func:`enable_compilation_cache` points JAX at ``FOLDER/xla`` (``abrdf_jax._cache.cache_dir``)
and stores every compiled function there, so the next process on this machine loads what an
earlier one compiled. A folder that cannot be written is a warning and a run without the cache.
This module imports JAX only inside :func:`enable_compilation_cache`.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

from ._errors import InputError
from .io._atomic import atomic_write, write_cause

XLA = "xla"
#: Bound of ``xla/``: least recently used entries past it are removed when the cache is enabled.
XLA_MAX_BYTES = 1 << 30
#: A temporary file older than this was left by a killed writer (removed by :func:`prune`).
STALE_TMP_SECS = 3600.0

Warn = Callable[[str], None]


def default_warn(message: str) -> None:
    warnings.warn(message, RuntimeWarning, stacklevel=3)


def _probe(folder: Path) -> None:
    """Create ``folder`` and write (and remove) a file in it; ``OSError`` when it cannot."""
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".probe.", suffix=".tmp")
    os.close(fd)
    os.unlink(tmp)


def os_reason(e: BaseException) -> str:
    return getattr(e, "strerror", None) or str(e) or type(e).__name__


def touch(path: Path) -> None:
    """Mark ``path`` as used now (its mtime orders :func:`prune`); a read-only cache skips it."""
    with contextlib.suppress(OSError):
        os.utime(path)


def prune(folder: Path, pattern: str, max_bytes: int, keep: Path | None = None) -> int:
    """Remove the least recently used files matching ``pattern`` in ``folder`` (never ``keep``)
    until their total is at most ``max_bytes``, and temporary files left by killed writers.
    Errors (a file another process removed, a read-only folder) are skipped. Returns the files
    removed."""
    now, removed, files = time.time(), 0, []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for e in entries:
        with contextlib.suppress(OSError):
            st = e.stat()
            if e.name.startswith(".") and e.name.endswith(".tmp"):
                if now - st.st_mtime > STALE_TMP_SECS:
                    os.unlink(e.path)
                    removed += 1
            elif fnmatch.fnmatch(e.name, pattern):
                files.append((st.st_mtime, st.st_size, e.path))
    total = sum(size for _, size, _ in files)
    for _, size, path in sorted(files):
        if total <= max_bytes:
            break
        if keep is not None and Path(path) == keep:
            continue
        with contextlib.suppress(OSError):
            os.unlink(path)
            removed += 1
        total -= size
    return removed


def enable_compilation_cache(folder: Path | None, warn: Warn = default_warn) -> bool:
    """Turn on JAX's persistent compilation cache in ``folder / "xla"``; never raises.

    Every compiled function is stored (no minimum compile time or size). Entries are written
    atomically (see :func:`_atomic_jax_cache`), so processes sharing the folder never read a
    half-written entry, and an unreadable entry is recompiled and replaced. The folder is kept
    under :data:`XLA_MAX_BYTES` (least recently used entries go first) each time this runs.

    Args:
        folder: the cache folder (:func:`cache_dir`); ``None``: nothing to do.
        warn: called with one message when the folder cannot be used.

    Returns:
        Whether the cache is on.
    """
    if folder is None:
        return False
    xla = Path(folder) / XLA
    try:
        _probe(xla)
    except OSError as e:
        warn(
            f"cannot write the compilation cache {xla} ({os_reason(e)}); running without the compilation cache"
        )
        return False
    try:
        import jax

        jax.config.update("jax_compilation_cache_dir", str(xla))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        _atomic_jax_cache(xla, warn)
        prune(xla, "*-cache", XLA_MAX_BYTES)
    except Exception as e:  # noqa: BLE001 - an unknown option in another JAX: run without it
        warn(
            f"cannot set up the compilation cache {xla} ({os_reason(e)}); running without the compilation cache"
        )
        with contextlib.suppress(Exception):
            jax.config.update("jax_compilation_cache_dir", None)
        return False
    return True


def disable_compilation_cache() -> None:
    """Turn JAX's persistent compilation cache off again in this process (tests that turned it on
    in a temporary folder call this before the folder goes)."""
    if "jax" not in sys.modules:
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", None)
    with contextlib.suppress(Exception):
        from jax._src import compilation_cache as cc

        cc.reset_cache()


def _atomic_jax_cache(path: Path, warn: Warn = default_warn) -> bool:
    """Put a cache object with atomic writes in JAX's place; ``False``: JAX's own is kept.

    JAX's file cache writes an entry in place (``Path.write_bytes``), so a process reading it
    meanwhile gets a truncated entry (a warning and a recompile), and an entry truncated by a
    killed process is never rewritten (``put`` skips existing files). This one writes a temporary
    file and renames it, and replaces an entry on ``put`` (JAX only puts after a failed read or
    a miss). Same file names as JAX's (``KEY-cache``). It uses JAX internals, checked here: in a
    JAX without them the config above (JAX's own cache) stays in place. A write that fails (disk
    full, a file-size limit) is one ``warn`` line, and the process stores nothing more (JAX would
    print a multi-line warning for each entry).
    """
    try:
        from jax._src import compilation_cache as cc
        from jax._src.compilation_cache_interface import CacheInterface
    except ImportError:
        return False
    if not all(
        hasattr(cc, n) for n in ("_cache", "_cache_initialized", "_cache_initialized_mutex")
    ):
        if hasattr(cc, "reset_cache"):
            cc.reset_cache()  # JAX reads the new folder on its next compile
        return False

    class AtomicFileCache(CacheInterface):
        def __init__(self, folder: Path):
            self._path = folder
            self._failed = False

        def get(self, key: str) -> bytes | None:
            path = self._path / f"{key}-cache"
            try:
                data = path.read_bytes()
            except FileNotFoundError:
                return None
            touch(path)
            return data

        def put(self, key: str, value: bytes) -> None:
            if self._failed:
                return
            try:
                # not fsync-ed: an entry lost or cut short by a crash is recompiled and replaced
                with atomic_write(self._path / f"{key}-cache", "wb", durable=False) as f:
                    f.write(value)
            except (OSError, InputError) as e:  # the temporary file is gone (atomic_write)
                self._failed = True
                warn(
                    f"cannot write the compilation cache {self._path} ({write_cause(e)}); "
                    "compiled functions of this run are not stored"
                )

    with cc._cache_initialized_mutex:
        cc._cache = AtomicFileCache(path)
        cc._cache_initialized = True
    return True
