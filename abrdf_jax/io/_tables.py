"""ABRDF tables (``.npz``, ``.exr``): reading, checking and writing.

Every reader turns a malformed file into an :class:`~abrdf_jax._errors.InputError` whose message
starts with ``path:line:`` (where a line applies), never a raw traceback from a library. Every
writer is atomic (:func:`~abrdf_jax.io._atomic.atomic_write`): the file appears complete or not at
all, and an existing file is only replaced once the new content has been fully written and
flushed to disk.

Formats:

- Measurement CSV: see :mod:`abrdf_jax.io._csv`.
- ABRDF table: ``table[i, v, c]``, shape ``(81, 81, 3)`` float32, as ``.npz`` (key ``abrdf``) or as
  an 81×81 RGB float EXR image whose row is the illumination index and column the view index.
- MERL ``.binary`` files: see :mod:`abrdf_jax.io._merl`.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from ._atomic import _check_readable, atomic_write, atomic_write_bytes
from .._errors import InputError, located
from ._exr import read_rgb_exr, write_rgb_exr
from ._npz import npz_bytes
from ._untrusted import check_archive

#: Shape of an ABRDF table on the UBO2003 grid.
TABLE_SHAPE = (81, 81, 3)
#: Key of the table inside an ``.npz`` file.
NPZ_KEY = "abrdf"
_TABLE_EXTENSIONS = (".npz", ".exr")


def _table_extension(path: Path) -> str:
    ext = path.suffix.lower()
    if ext not in _TABLE_EXTENSIONS:
        raise InputError(
            f"{path}: unknown table format {path.suffix!r}; "
            f"use one of {', '.join(_TABLE_EXTENSIONS)}"
        )
    return ext


def check_table(table, where: str) -> np.ndarray:
    """Finite float32 array of shape ``TABLE_SHAPE``, else an InputError starting ``where``."""
    arr = np.asarray(table)
    _check_table_header(arr.shape, arr.dtype, where)
    with np.errstate(over="ignore"):
        arr = arr.astype(np.float32, copy=False)  # a float32 table as it is
    bad = ~np.isfinite(arr)
    if bad.any():
        i, v, c = np.argwhere(bad)[0]
        raise InputError(
            f"{where}: table holds {int(bad.sum())} NaN or infinite value(s) (in float32), "
            f"first at [illumination {i}, view {v}, channel {'RGB'[c]}]"
        )
    return arr


def read_table(path: str | os.PathLike) -> np.ndarray:
    """Read one ABRDF table from ``.npz`` (key ``abrdf``) or ``.exr``.

    An EXR file must be a single 81×81 image with float (32- or 16-bit) channels ``R``, ``G``,
    ``B`` (others, such as ``A``, are ignored); row ``i`` is the illumination index and column
    ``v`` the view index.

    Args:
        path: the file (str or path-like); the format is chosen by its extension.

    Returns:
        float32 numpy array of shape ``(81, 81, 3)``, ``table[i, v, c]``.

    Raises:
        InputError: unknown extension; missing, truncated or corrupt file; no ``abrdf`` key or no
            R, G, B channels; wrong shape; non-float data; NaN or infinite values.
    """
    path = Path(path)
    ext = _table_extension(path)
    _check_readable(path)
    if ext == ".npz":
        table = _read_npz(path)
    else:
        table = read_rgb_exr(path, TABLE_SHAPE[:2])
    return check_table(table, str(path))


def _read_npz(path: Path) -> np.ndarray:
    """The ``abrdf`` array of an ``.npz`` archive; shape and dtype are checked from the array's
    header before its data are read, so a wrong (e.g. huge) array costs nothing."""
    member = NPZ_KEY + ".npy"
    try:
        with zipfile.ZipFile(path) as zf:
            check_archive(zf, path)
            names = zf.namelist()
            if member not in names:
                held = ", ".join(n.removesuffix(".npy") for n in names) or "nothing"
                raise located(f"no array named {NPZ_KEY!r}; the archive holds {held}", path)
            with zf.open(member) as m:
                version = np.lib.format.read_magic(m)
                if version in ((1, 0), (2, 0)):
                    read_header = getattr(np.lib.format, f"read_array_header_{version[0]}_0")
                    shape, _, dtype = read_header(m)
                    _check_table_header(shape, dtype, str(path))
            with zf.open(member) as m:
                return np.lib.format.read_array(m, allow_pickle=False)
    except InputError:
        raise
    except zipfile.BadZipFile as e:
        with open(path, "rb") as f:
            magic = f.read(6)
        if magic == b"\x93NUMPY":
            raise located(
                f"a bare .npy array, not an .npz archive; save it with "
                f"numpy.savez(path, {NPZ_KEY}=table)",
                path,
            ) from e
        raise located(f"not an .npz archive (truncated or corrupt?): {e}", path) from e
    except OSError as e:
        if e.errno is not None:  # permission and the like
            raise located(f"cannot read: {e.strerror or e}", path) from e
        raise located(f"cannot read as .npz (truncated or corrupt?): {e}", path) from e
    except Exception as e:  # noqa: BLE001 - zipfile, zlib and numpy raise many types
        raise located(f"cannot read as .npz (truncated or corrupt?): {e}", path) from e


def _check_table_header(shape, dtype, where: str) -> None:
    """Shape and dtype checks of :func:`check_table`, from an array header alone."""
    shape = tuple(shape)
    if shape != TABLE_SHAPE:
        stack = len(shape) == 4 and shape[1:] == TABLE_SHAPE
        hint = " (a stack of tables: select one, e.g. array[k])" if stack else ""
        raise InputError(f"{where}: table has shape {shape}, expected {TABLE_SHAPE}{hint}")
    if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
        raise InputError(f"{where}: table has dtype {dtype}, expected a real floating type")


def write_tables(paths, tables) -> None:
    """:func:`write_table` with ``durable=False`` for each ``(path, table)``: a folder run's
    batch, one task of a writer thread. The first failure raises; the tables before it are
    complete files.

    Raises:
        InputError: as :func:`write_table`.
    """
    for path, table in zip(paths, tables, strict=True):
        write_table(path, table, durable=False)


def write_table(
    path: str | os.PathLike, table, *, durable: bool = True, comment: str | None = None
) -> None:
    """Write one ABRDF table atomically as ``.npz`` (key ``abrdf``) or ``.exr``.

    ``.npz`` tables are stored uncompressed (79 kB): deflating one took 4.5 ms against 0.3 ms
    for the write (a folder run writes thousands) for files 2.6x smaller; the archive is built
    in memory (:func:`abrdf_jax.io._npz.npz_bytes`, not ``numpy.savez``); ``.exr`` files are
    ZIP-compressed.

    EXR files hold float32 channels ``R``, ``G``, ``B`` (ZIP, lossless), row = illumination index,
    column = view index, so that :func:`read_table` returns the table bit for bit.

    Args:
        path: the destination (str or path-like); the format is chosen by its extension.
        table: array-like of shape ``(81, 81, 3)``; converted to float32.
        durable: as :func:`abrdf_jax.io.atomic_write` (``False``: renamed into place without
            ``fsync``; a folder run's tables, whose ``--resume`` reads every table it keeps).
        comment: an ``.exr`` file's header comment (default: what an ABRDF table holds); for
            arrays of the table's layout that are not tables (a standard deviation).

    Raises:
        InputError: unknown extension, wrong shape, non-real dtype, NaN or infinite values (also
            after the float32 conversion), or the file cannot be written.
    """
    path = Path(path)
    ext = _table_extension(path)
    arr = check_table(table, f"cannot write {path}")
    if ext == ".npz":
        data = npz_bytes(NPZ_KEY, arr)  # stored, not deflated: docstring; built in memory
        if not durable:  # a folder run's (thousands): system calls, no file object
            atomic_write_bytes(path, data)
            return
        with atomic_write(path, "wb") as f:
            f.write(data)
    else:
        write_rgb_exr(
            path,
            arr,
            comment=comment
            or "abrdf_jax ABRDF table: row = illumination index, column = view index "
            "(UBO2003 81-direction grid), linear RGB BRDF*cos(theta_i)",
            durable=durable,
        )
