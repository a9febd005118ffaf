"""Training tables from files: ``.npz``/``.exr`` tables, stacks of tables, MERL ``.binary`` files.

Each input is recorded (name, sha256 of the table's float32 bytes, the file and its sha256), so
a prior file says what it was trained on.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from .._errors import InputError, located
from .._names import PRIOR_INPUT_SUFFIXES
from ..io._atomic import _check_readable
from ..io._untrusted import check_npz
from ..io._atomic import file_sha256 as _file_sha256

SUFFIXES = PRIOR_INPUT_SUFFIXES


def _table_sha256(table: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(table, np.float32).tobytes()).hexdigest()


def _npz_stack(path: Path, split: str | None):
    """A stack ``abrdf`` ``(N, 81, 81, 3)`` (with optional ``names``, ``split``), or ``None``."""
    try:
        check_npz(path)  # member names, sizes and array headers, before anything is inflated
        with np.load(path, allow_pickle=False) as z:
            if "abrdf" not in z.files or z["abrdf"].ndim != 4:
                return None
            stack = np.asarray(z["abrdf"])
            names = [str(n) for n in z["names"]] if "names" in z.files else None
            splits = [str(s) for s in z["split"]] if "split" in z.files else None
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - zipfile/numpy errors: read_table reports them
        del e
        return None
    if stack.shape[1:] != (81, 81, 3):
        raise located(f"'abrdf' has shape {stack.shape}, expected (N, 81, 81, 3)", path)
    names = names or [f"{path.stem}[{i}]" for i in range(len(stack))]
    if len(names) != len(stack):
        raise located(f"'names' has {len(names)} entries for {len(stack)} tables", path)
    keep = np.arange(len(stack))
    if split is not None:
        if splits is None:
            raise located(f"--split {split!r} asked for, but the file has no 'split' array", path)
        keep = np.nonzero(np.asarray(splits) == split)[0]
        if keep.size == 0:
            raise located(
                f"no table has split {split!r} (the file has {sorted(set(splits))})", path
            )
    return stack[keep].astype(np.float32), [names[i] for i in keep], keep


def _merl_table(path: Path) -> np.ndarray:
    from ..io._merl import MERLMaterial, read_merl_binary
    from ..materials._registry import dense_table

    return dense_table(MERLMaterial(read_merl_binary(path)), np.float32)


def read_training_tables(paths, split: str | None = None):
    """Read every input into one stack of training tables.

    Args:
        paths: files: ``.npz`` or ``.exr`` tables (:func:`abrdf_jax.io.read_table`), ``.npz``
            stacks with ``abrdf`` of shape ``(N, 81, 81, 3)`` (and optional ``names``, ``split``:
            e.g. the merl-nbrdf ``tables81.npz``), MERL ``.binary`` files (resampled on the UBO
            grid by nearest-bin lookup, :class:`abrdf_jax.io.MERLMaterial`).
        split: keep only the entries of stacks whose ``split`` equals this (e.g. ``"train"``).

    Returns:
        ``(tables (N, 81, 81, 3) float32, names, sources)``; ``sources[i]`` is a dict with
        ``name``, ``sha256`` (the table's float32 bytes), ``source`` (file, ``#index`` for a
        stack) and ``file_sha256``.

    Raises:
        InputError: a missing or unreadable file, an unknown suffix, a bad table, duplicate
            names, or no table at all.
    """
    from ..io._tables import read_table

    tables, names, sources = [], [], []
    for p in map(Path, paths):
        ext = p.suffix.lower()
        if ext not in SUFFIXES:
            raise InputError(f"{p}: unknown training input {p.suffix!r}; use {', '.join(SUFFIXES)}")
        _check_readable(p)
        digest = _file_sha256(p)
        stack = _npz_stack(p, split) if ext == ".npz" else None
        if stack is not None:
            arr, nm, idx = stack
            items = [(t, n, f"{p}#{i}") for t, n, i in zip(arr, nm, idx)]
        elif ext == ".binary":
            items = [(_merl_table(p), p.stem, str(p))]
        else:
            items = [(read_table(p), p.stem, str(p))]
        for t, n, src in items:
            if np.any(t < 0):
                raise InputError(f"{src}: table holds negative values; an ABRDF is non-negative")
            tables.append(t)
            names.append(n)
            sources.append(
                {"name": n, "sha256": _table_sha256(t), "source": src, "file_sha256": digest}
            )
    if not tables:
        raise InputError("no training tables given")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"duplicate training names: {', '.join(dup[:5])}")
    return np.stack(tables), names, sources
