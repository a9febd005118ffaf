"""Measurement CSV files (``PROTOCOL.md``, "Measurement file"): a streaming reader and a writer.

Header ``theta_i,phi_i,theta_v,phi_v,r,g,b``, one sample a row, angles in degrees, linear RGB
ABRDF values (BRDF · cos θi).

The reader streams the file in blocks of whole lines (:data:`BLOCK_BYTES`), so a file of millions
of rows costs its output arrays (56 bytes a row, allocated once from a count of the lines) plus a
few MiB. A block is parsed by numpy's C parser (``numpy.loadtxt``) when it is plain (no quotes,
every field a number); any block that the fast path does not accept completely is parsed again
row by row with the :mod:`csv` module, which finds the first bad row and names its line. Both
paths accept the same files and give the same numbers (Python's ``float`` and numpy's parser both
round correctly).
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from ._atomic import _check_readable, atomic_write
from .._arrays import SampleColumns
from .._errors import InputError, located

if (
    TYPE_CHECKING
):  # the class imports JAX: the reader needs it only for a file that passed every check
    from .._measurements import Samples

#: Column names of a measurement CSV file, in the order the writer uses.
CSV_COLUMNS = ("theta_i", "phi_i", "theta_v", "phi_v", "r", "g", "b")
_ANGLE_COLUMNS = CSV_COLUMNS[:4]
#: Accepted angle ranges in degrees (inclusive). φ is taken modulo 360 downstream; the range only
#: catches garbage (and some radian/degree mix-ups) early.
THETA_RANGE = (0.0, 90.0)
PHI_RANGE = (-360.0, 720.0)
#: Bytes read at a time; a block always ends at a line end.
BLOCK_BYTES = 1 << 20
_BOM = b"\xef\xbb\xbf"
#: Radian detection (see :func:`_check_units`): at least this many rows before judging.
_RADIAN_MIN_ROWS = 4
_RADIAN_MIN_ROWS_PHI = 20


# --------------------------------------------------------------------------------------------
# Header
# --------------------------------------------------------------------------------------------


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


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


# --------------------------------------------------------------------------------------------
# Streaming
# --------------------------------------------------------------------------------------------


def _blocks(f: BinaryIO) -> Iterator[tuple[int, int, bytes]]:
    """``(first line number, byte offset, data)`` of consecutive blocks of whole lines."""
    line, offset, rest = 1, 0, b""
    while True:
        chunk = f.read(BLOCK_BYTES)
        if not chunk:
            if rest:
                yield line, offset, rest
            return
        buf = rest + chunk
        cut = buf.rfind(b"\n") + 1
        if cut == 0:  # a line longer than a block: keep reading
            rest = buf
            continue
        block, rest = buf[:cut], buf[cut:]
        yield line, offset, block
        line += block.count(b"\n")
        offset += cut


def _decode(data: bytes, path: Path, line0: int, offset: int) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = line0 + data.count(b"\n", 0, e.start)
        raise located(
            f"not a UTF-8 text file ({e.reason} at byte {offset + e.start})", path, line
        ) from None


def _take_header(text: str, path: Path, line0: int):
    """Find the header in the first non-blank line of ``text``.

    Returns ``(index, n_fields, rest_text, rest_line)``, or ``index = None`` when ``text`` holds
    only blank lines.
    """
    pos, line = 0, line0
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end + 1
        raw = text[pos:end].rstrip("\n").removesuffix("\r")
        pos = end
        if "\r" in raw:
            raise located(
                "line ends in a bare carriage return (old Mac text format); "
                "convert the file to \\n or \\r\\n line ends",
                path,
                line,
            )
        try:
            fields = next(csv.reader([raw], strict=True), [])
        except csv.Error as e:
            raise located(f"malformed CSV: {e}", path, line) from e
        if any(x.strip() for x in fields):
            return _parse_header(fields, path, line), len(fields), text[pos:], line + 1
        line += 1
    return None, 0, "", line


_RANGES = {"theta_i": THETA_RANGE, "theta_v": THETA_RANGE, "phi_i": PHI_RANGE, "phi_v": PHI_RANGE}
_LO, _HI = np.array([_RANGES[c] for c in _ANGLE_COLUMNS]).T  # per angle column


def _check_values(name: str, value: float, text: str, path: Path, line: int) -> None:
    """Finite, and an angle within its accepted range; else an InputError at ``path:line``."""
    if not math.isfinite(value):
        raise located(f"column {name!r}: value {text.strip()!r} is not finite", path, line)
    if name in _RANGES:
        lo, hi = _RANGES[name]
        if not lo <= value <= hi:
            raise located(f"{name} = {value:g} degrees is outside [{lo:g}, {hi:g}]", path, line)


def _parse_slow(text: str, path: Path, line0: int, index: list[int]) -> np.ndarray:
    """Row-by-row parse with exact ``path:line`` messages; ``(rows, 7)`` float64."""
    need = max(index) + 1
    out: list[list[float]] = []
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        for fields in reader:
            line = line0 + reader.line_num - 1
            if not any(x.strip() for x in fields):
                continue
            if len(fields) < need:
                raise located(f"expected at least {need} fields, got {len(fields)}", path, line)
            row = []
            for k, name in zip(index, CSV_COLUMNS):
                text_k = fields[k]
                try:
                    value = float(text_k)
                except ValueError:
                    raise located(
                        f"column {name!r}: cannot read {text_k.strip()!r} as a number", path, line
                    ) from None
                _check_values(name, value, text_k, path, line)
                row.append(value)
            out.append(row)
    except csv.Error as e:
        raise located(f"malformed CSV: {e}", path, line0 + reader.line_num - 1) from e
    return np.asarray(out, dtype=np.float64).reshape(-1, len(CSV_COLUMNS))


def _parse_fast(text: str, index: list[int]) -> np.ndarray | None:
    """numpy's C parser on a plain block; ``None`` when the block needs the row-by-row path."""
    if '"' in text:
        return None
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" on blank-only blocks
            arr = np.loadtxt(
                lines, delimiter=",", comments=None, usecols=index, dtype=np.float64, ndmin=2
            )
    except ValueError:
        return None
    if arr.shape[1] != len(CSV_COLUMNS) or not np.isfinite(arr).all():
        return None
    angles = arr[:, : len(_ANGLE_COLUMNS)]
    return arr if ((angles >= _LO) & (angles <= _HI)).all() else None


def _count_lines(f: BinaryIO) -> int:
    n = 1
    for chunk in iter(lambda: f.read(1 << 22), b""):
        n += chunk.count(b"\n")
    f.seek(0)
    return n


def read_samples_csv(path: str | os.PathLike) -> Samples:
    """Read a measurement CSV file (``PROTOCOL.md``, "Measurement file") as
    :class:`~abrdf_jax.Samples`: :func:`read_sample_columns`, whose rules and errors it has.
    """
    return read_sample_columns(path).to_samples()


def read_sample_columns(path: str | os.PathLike) -> SampleColumns:
    """Read a measurement CSV file (``PROTOCOL.md``, "Measurement file") into numpy columns.

    The header must name the seven columns ``theta_i,phi_i,theta_v,phi_v,r,g,b`` (surrounding
    whitespace and letter case are ignored, any order); other columns are ignored. Blank lines are
    skipped; ``\\n`` and ``\\r\\n`` line ends and a UTF-8 byte-order mark are accepted. The file
    is streamed in blocks: memory is the output (56 bytes a row) plus a few MiB, whatever its size.

    Accepted values: finite numbers; ``θ`` in ``[0, 90]`` degrees; ``φ`` in ``[-360, 720]``
    degrees (taken modulo 360 downstream). Negative RGB values are accepted and kept: a
    dark-frame subtraction leaves small negative values in real measurements, and clipping them
    here would bias the reconstruction (the command line reports them; the reconstruction is
    clamped at 0).

    Args:
        path: the file (str or path-like).

    Returns:
        The columns (a ``SampleColumns``: the fields of :class:`~abrdf_jax.Samples`, float64
        numpy arrays, angles in degrees, in file order); no JAX is imported.

    Raises:
        InputError: (message ``path:line: ...``) the file is missing, unreadable, not UTF-8 text or
            empty; the header is missing or lacks columns; a row has too few fields, a field that
            is not a number, a NaN or infinite value, or an angle out of range; there are no data
            rows; or the angles look like radians (see :func:`_check_units`).
    """
    path = Path(path)
    _check_readable(path)
    try:
        with open(path, "rb") as f:
            n_max = _count_lines(f)
            angles = np.empty((4, n_max))
            rgb = np.empty((n_max, 3))
            n = 0
            index = None
            for line0, offset, data in _blocks(f):
                if offset == 0 and data.startswith(_BOM):
                    data, offset = data[len(_BOM) :], len(_BOM)
                text = _decode(data, path, line0, offset)
                if index is None:
                    index, _, text, line0 = _take_header(text, path, line0)
                    if index is None:
                        continue
                rows = _parse_fast(text, index)
                if rows is None:
                    rows = _parse_slow(text, path, line0, index)
                k = rows.shape[0]
                if n + k > n_max:  # the file grew while we read it
                    raise located("file changed while it was read", path)
                angles[:, n : n + k] = rows[:, :4].T
                rgb[n : n + k] = rows[:, 4:]
                n += k
    except OSError as e:
        raise located(f"cannot read: {e.strerror or e}", path) from e
    if index is None:
        raise located(f"empty file; expected the header {','.join(CSV_COLUMNS)}", path, 1)
    if n == 0:
        raise located("no data rows after the header", path)
    if n < n_max // 2:  # mostly blank lines: do not keep the spare rows alive
        angles, rgb = angles[:, :n].copy(), rgb[:n].copy()
    ti, pi, tv, pv = angles[0, :n], angles[1, :n], angles[2, :n], angles[3, :n]
    _check_units(path, ti, pi, tv, pv)
    return SampleColumns(ti, pi, tv, pv, rgb[:n])


def _check_units(path: Path, ti, pi, tv, pv) -> None:
    """Reject files whose angles are evidently in radians.

    Two rules, both on the whole file:

    - all angles: at least 4 rows, every ``|angle| <= 2π``, every ``θ <= π/2`` and some nonzero
      ``φ``. In degrees that would mean every direction within 1.6° of the normal and every
      azimuth within ±6.3° — no real measurement looks like that, and a file in radians always does.
    - azimuths only (elevations in degrees, azimuths in radians): at least 20 rows, some ``θ``
      above π/2 (so θ is in degrees), every ``|φ| <= 2π``, and ``φi`` or ``φv`` spread over more
      than π with a non-integer value. A slice measurement in degrees spans tens of degrees of
      azimuth; one confined to a 12.6° window with fractional values reads as radians.
    """
    if ti.size < _RADIAN_MIN_ROWS:
        return
    two_pi = 2 * np.pi
    phi_small = max(np.abs(pi).max(), np.abs(pv).max()) <= two_pi
    theta_max = max(ti.max(), tv.max())
    if phi_small and theta_max <= np.pi / 2 + 1e-9 and (np.any(pi != 0) or np.any(pv != 0)):
        raise located(
            "the angles look like radians (every |angle| <= 2*pi and every theta <= pi/2 over "
            f"{ti.size} rows); the file must give angles in degrees",
            path,
        )
    if phi_small and ti.size >= _RADIAN_MIN_ROWS_PHI and theta_max > np.pi / 2:
        spread = max(np.ptp(pi), np.ptp(pv))
        fractional = np.any(pi != np.round(pi)) or np.any(pv != np.round(pv))
        if spread > np.pi and fractional:
            raise located(
                "the azimuths look like radians while the elevations are in degrees (every "
                f"|phi| <= 2*pi over {ti.size} rows, spread {spread:.3g}, theta up to "
                f"{theta_max:g}); the file must give all angles in degrees",
                path,
            )


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------


def _row_text(row) -> str:
    """One data line; ``repr`` is the shortest text that reads back to the same float64."""
    return ",".join(map(repr, row)) + "\n"


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
        lo, hi = _RANGES[name]
        out = (data[:, k] < lo) | (data[:, k] > hi)
        if out.any():
            row = int(np.argmax(out))
            raise InputError(
                f"cannot write {path}: sample {row} has {name} = {data[row, k]:g} degrees, "
                f"outside [{lo:g}, {hi:g}]"
            )
    with atomic_write(path, "w", newline="") as f:
        f.write(",".join(CSV_COLUMNS) + "\n")
        for row in data.tolist():
            f.write(_row_text(row))
