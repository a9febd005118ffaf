"""File input and output: atomic writes, measurement CSV files and ABRDF tables.

Every reader turns a malformed file into an :class:`~abrdf_jax._errors.InputError` whose message
starts with ``path:line:`` (where a line applies), never a raw traceback from a library. Every
writer is atomic: the file appears complete or not at all, and an existing file is only replaced
once the new content has been fully written and flushed to disk.

Formats:

- Measurement CSV (``PROTOCOL.md``, "Measurement file"): header
  ``theta_i,phi_i,theta_v,phi_v,r,g,b``, one sample a row, angles in degrees, linear RGB ABRDF
  values (BRDF · cos θi).
- ABRDF table: ``table[i, v, c]``, shape ``(81, 81, 3)`` float32, as ``.npz`` (key ``abrdf``) or as
  an 81×81 RGB float EXR image whose row is the illumination index and column the view index.
- MERL ``.binary`` files: see :mod:`abrdf_jax._merl`.
"""

from __future__ import annotations

import array
import contextlib
import csv
import math
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from ._errors import InputError, located
from ._samples import Samples

#: Column names of a measurement CSV file, in the order the writer uses.
CSV_COLUMNS = ("theta_i", "phi_i", "theta_v", "phi_v", "r", "g", "b")
_ANGLE_COLUMNS = CSV_COLUMNS[:4]
#: Shape of an ABRDF table on the UBO2003 grid.
TABLE_SHAPE = (81, 81, 3)
#: Key of the table inside an ``.npz`` file.
NPZ_KEY = "abrdf"
_TABLE_EXTENSIONS = (".npz", ".exr")


# --------------------------------------------------------------------------------------------
# Atomic writes
# --------------------------------------------------------------------------------------------


def _current_umask() -> int:
    # os.umask can only be read by setting it; restore it at once.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(
    path: str | os.PathLike, mode: str = "wb", *, newline: str | None = None
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

    Yields:
        The open temporary file object.

    Raises:
        InputError: the folder does not exist or is not writable, ``path`` is a folder, or the
            rename fails.
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
        try:
            os.fchmod(fd, 0o666 & ~_current_umask())
        except (AttributeError, OSError):  # fchmod is POSIX only; mkstemp's 0o600 is still safe
            pass
        if "b" in mode:
            f = os.fdopen(fd, mode)
        else:
            f = os.fdopen(fd, "w", encoding="utf-8", newline=newline)
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        try:
            os.replace(tmp, path)
        except OSError as e:
            raise InputError(f"cannot write {path}: {e.strerror}") from e
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_folder(folder)


def _fsync_folder(folder: Path) -> None:
    # Make the rename itself durable; not possible (nor needed) on every platform.
    try:
        dfd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise located("file not found", path)
    if path.is_dir():
        raise located("is a folder, not a file", path)


# --------------------------------------------------------------------------------------------
# Measurement CSV
# --------------------------------------------------------------------------------------------


def _parse_header(fields: list[str], path: Path, line: int) -> list[int]:
    """Column index of each of ``CSV_COLUMNS``; raises on a missing header or missing names."""
    names = [f.strip().lower() for f in fields]
    index: dict[str, int] = {}
    for k, name in enumerate(names):
        if name in CSV_COLUMNS:
            if name in index:
                raise located(f"column {name!r} appears twice in the header", path, line)
            index[name] = k
    missing = [c for c in CSV_COLUMNS if c not in index]
    if missing:
        if not index and all(_is_number(f) for f in fields if f.strip()):
            raise located(
                "the first line looks like data, not a header; expected the header "
                f"{','.join(CSV_COLUMNS)}",
                path,
                line,
            )
        raise located(
            f"header lacks column(s) {', '.join(missing)}; expected {','.join(CSV_COLUMNS)} "
            f"(any order), got {','.join(f.strip() for f in fields)}",
            path,
            line,
        )
    return [index[c] for c in CSV_COLUMNS]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_samples_csv(path: str | os.PathLike) -> Samples:
    """Read a measurement CSV file (``PROTOCOL.md``, "Measurement file").

    The header must name the seven columns ``theta_i,phi_i,theta_v,phi_v,r,g,b`` (surrounding
    whitespace and letter case are ignored, any order); other columns are ignored. Blank lines are
    skipped. The file is parsed row by row, so memory beyond the output arrays stays bounded.

    Accepted values: finite numbers; ``θ`` in ``[0, 90]`` degrees; ``φ`` in ``[-360, 720]``
    degrees (taken modulo 360 downstream). Negative RGB values are accepted: a dark-frame
    subtraction leaves small negative values in real measurements, and clipping them here would
    bias the reconstruction.

    Args:
        path: the file (str or path-like).

    Returns:
        :class:`~abrdf_jax._samples.Samples` holding float64 numpy arrays, angles in degrees, in
        file order.

    Raises:
        InputError: (message ``path:line: ...``) the file is missing, unreadable, not UTF-8 text or
            empty; the header is missing or lacks columns; a row has too few fields, a field that
            is not a number, a NaN or infinite value, or an angle out of range; there are no data
            rows; or every angle fits in ``[-2π, 2π]`` with all ``θ ≤ π/2`` over at least four
            rows with some nonzero ``φ`` (the angles look like radians).
    """
    path = Path(path)
    _check_readable(path)
    cols = [array.array("d") for _ in CSV_COLUMNS]
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            reader = csv.reader(f, strict=True)
            index = None
            need = 0
            try:
                for fields in reader:
                    line = reader.line_num
                    if not any(x.strip() for x in fields):
                        continue
                    if index is None:
                        index = _parse_header(fields, path, line)
                        need = max(index) + 1
                        continue
                    if len(fields) < need:
                        raise located(
                            f"expected at least {need} fields, got {len(fields)}", path, line
                        )
                    for col, k, name in zip(cols, index, CSV_COLUMNS):
                        text = fields[k]
                        try:
                            value = float(text)
                        except ValueError:
                            raise located(
                                f"column {name!r}: cannot read {text.strip()!r} as a number",
                                path,
                                line,
                            ) from None
                        if not math.isfinite(value):
                            raise located(
                                f"column {name!r}: value {text.strip()!r} is not finite", path, line
                            )
                        if name.startswith("theta") and not 0.0 <= value <= 90.0:
                            raise located(
                                f"{name} = {value:g} degrees is outside [0, 90]", path, line
                            )
                        if name.startswith("phi") and not -360.0 <= value <= 720.0:
                            raise located(
                                f"{name} = {value:g} degrees is outside [-360, 720]", path, line
                            )
                        col.append(value)
            except csv.Error as e:
                raise located(f"malformed CSV: {e}", path, reader.line_num) from e
    except UnicodeDecodeError as e:
        raise located(f"not a UTF-8 text file ({e.reason} at byte {e.start})", path) from e
    except OSError as e:
        raise located(f"cannot read: {e.strerror or e}", path) from e
    if index is None:
        raise located(f"empty file; expected the header {','.join(CSV_COLUMNS)}", path, 1)
    if len(cols[0]) == 0:
        raise located("no data rows after the header", path)
    ti, pi, tv, pv, r, g, b = (np.frombuffer(c, dtype=np.float64).copy() for c in cols)
    _reject_radians(path, ti, pi, tv, pv)
    return Samples(ti, pi, tv, pv, np.stack([r, g, b], axis=-1))


def _reject_radians(path: Path, ti, pi, tv, pv) -> None:
    # In degrees, every θ <= π/2 means every direction within 1.6° of the normal and every φ
    # within ±6.3°: no real measurement looks like that, a file written in radians always does.
    angles = np.concatenate([ti, pi, tv, pv])
    if (
        ti.size >= 4
        and np.all(np.abs(angles) <= 2 * np.pi)
        and max(ti.max(), tv.max()) <= np.pi / 2 + 1e-9
        and (np.any(pi != 0) or np.any(pv != 0))
    ):
        raise located(
            "the angles look like radians (every |angle| <= 2*pi and every theta <= pi/2); "
            "the file must give angles in degrees",
            path,
        )


def _float_text(x: float) -> str:
    # repr gives the shortest text that reads back to the same float64.
    return repr(float(x))


def write_samples_csv(path: str | os.PathLike, samples: Samples) -> None:
    """Write samples as a measurement CSV file, atomically, at full float64 precision.

    Args:
        path: the destination file (str or path-like).
        samples: the samples; angles in degrees.

    Raises:
        InputError: a value is NaN or infinite, an angle is outside the range the reader
            accepts, or the file cannot be written.
    """
    path = Path(path)
    s = samples.to_numpy()
    data = np.column_stack(
        [np.asarray(getattr(s, c), dtype=np.float64) for c in _ANGLE_COLUMNS]
        + [np.asarray(s.rgb, dtype=np.float64).reshape(-1, 3)]
    )
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise InputError(
            f"cannot write {path}: sample {row} has a non-finite {CSV_COLUMNS[col]} "
            f"({data[row, col]}); {int(bad.any(axis=1).sum())} sample(s) affected"
        )
    for k, name in enumerate(_ANGLE_COLUMNS):
        lo, hi = (0.0, 90.0) if name.startswith("theta") else (-360.0, 720.0)
        out = (data[:, k] < lo) | (data[:, k] > hi)
        if out.any():
            row = int(np.argmax(out))
            raise InputError(
                f"cannot write {path}: sample {row} has {name} = {data[row, k]:g} degrees, "
                f"outside [{lo:g}, {hi:g}]"
            )
    with atomic_write(path, "w", newline="") as f:
        f.write(",".join(CSV_COLUMNS) + "\n")
        for row in data:
            f.write(",".join(map(_float_text, row)) + "\n")


# --------------------------------------------------------------------------------------------
# ABRDF tables
# --------------------------------------------------------------------------------------------


def _table_extension(path: Path) -> str:
    ext = path.suffix.lower()
    if ext not in _TABLE_EXTENSIONS:
        raise InputError(
            f"{path}: unknown table format {path.suffix!r}; "
            f"use one of {', '.join(_TABLE_EXTENSIONS)}"
        )
    return ext


def _check_table(table, where: str) -> np.ndarray:
    """Finite float32 array of shape ``TABLE_SHAPE``, else an InputError starting ``where``."""
    arr = np.asarray(table)
    if arr.shape != TABLE_SHAPE:
        hint = ""
        if arr.ndim == 4 and arr.shape[1:] == TABLE_SHAPE:
            hint = " (a stack of tables: select one, e.g. array[k])"
        raise InputError(f"{where}: table has shape {arr.shape}, expected {TABLE_SHAPE}{hint}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{where}: table has dtype {arr.dtype}, expected a real floating type")
    with np.errstate(over="ignore"):
        arr = arr.astype(np.float32)
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
        table = _read_exr(path)
    return _check_table(table, str(path))


def _read_npz(path: Path) -> np.ndarray:
    try:
        with np.load(path, allow_pickle=False) as z:
            if not isinstance(z, np.lib.npyio.NpzFile):
                raise located("not an .npz archive (a bare .npy array?)", path)
            if NPZ_KEY not in z.files:
                raise located(
                    f"no array named {NPZ_KEY!r}; "
                    f"the archive holds {', '.join(z.files) or 'nothing'}",
                    path,
                )
            return z[NPZ_KEY]
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - zipfile, zlib and numpy raise many types
        raise located(f"cannot read as .npz (truncated or corrupt?): {e}", path) from e


def _exr():
    try:
        import OpenEXR
    except ImportError as e:  # pragma: no cover - OpenEXR is a dependency
        raise InputError(
            "reading or writing .exr needs the OpenEXR package (pip install OpenEXR)"
        ) from e
    return OpenEXR


def _read_exr(path: Path) -> np.ndarray:
    OpenEXR = _exr()
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
        parts = f.parts
    except Exception as e:  # noqa: BLE001 - the library raises RuntimeError, IndexError, ...
        raise located(f"cannot read as OpenEXR (truncated or corrupt?): {e}", path) from e
    if len(parts) == 0:
        # OpenEXR 3.x returns no parts when the pixel data cannot be decoded (truncated file).
        raise located(
            "cannot read as OpenEXR: no readable image part (truncated or corrupt?)", path
        )
    if len(parts) > 1:
        raise located(f"multi-part EXR ({len(parts)} parts); expected one 81x81 RGB image", path)
    channels = parts[0].channels
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise located(
            f"EXR lacks channel(s) {', '.join(missing)}; "
            f"it has {', '.join(sorted(channels)) or 'none'}",
            path,
        )
    planes = []
    for c in "RGB":
        px = np.asarray(channels[c].pixels)
        if px.dtype not in (np.float32, np.float16):
            raise located(
                f"EXR channel {c} has pixel type {px.dtype}, expected float or half", path
            )
        if px.shape != TABLE_SHAPE[:2]:
            raise located(
                f"EXR image is {px.shape[1] if px.ndim > 1 else '?'}x{px.shape[0]} "
                "(width x height), "
                f"expected 81x81",
                path,
            )
        planes.append(px.astype(np.float32))
    return np.stack(planes, axis=-1)


def write_table(path: str | os.PathLike, table) -> None:
    """Write one ABRDF table atomically as ``.npz`` (key ``abrdf``, compressed) or ``.exr``.

    EXR files hold float32 channels ``R``, ``G``, ``B`` (ZIP, lossless), row = illumination index,
    column = view index, so that :func:`read_table` returns the table bit for bit.

    Args:
        path: the destination (str or path-like); the format is chosen by its extension.
        table: array-like of shape ``(81, 81, 3)``; converted to float32.

    Raises:
        InputError: unknown extension, wrong shape, non-real dtype, NaN or infinite values (also
            after the float32 conversion), or the file cannot be written.
    """
    path = Path(path)
    ext = _table_extension(path)
    arr = _check_table(table, f"cannot write {path}")
    if ext == ".npz":
        with atomic_write(path, "wb") as f:
            np.savez_compressed(f, **{NPZ_KEY: arr})
    else:
        OpenEXR = _exr()
        header = {
            "compression": OpenEXR.ZIP_COMPRESSION,
            "type": OpenEXR.scanlineimage,
            "comment": "abrdf_jax ABRDF table: row = illumination index, column = view index "
            "(UBO2003 81-direction grid), linear RGB BRDF*cos(theta_i)",
        }
        channels = {c: np.ascontiguousarray(arr[..., k]) for k, c in enumerate("RGB")}
        image = OpenEXR.File(header, channels)
        with atomic_write(path, "wb") as f:
            image.write(f)
