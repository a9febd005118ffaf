"""Reading files that may be hostile: zip members and declared sizes, checked before reading.

The package reads archives (``.npz`` tables and prior files, the zip archives of BTF images) and
formats whose header declares how much data follows (``.npy`` members, EXR, PNG). It never
extracts anything to disk and never unpickles (every ``np.load`` passes ``allow_pickle=False``),
and it bounds what one member or one image may unpack to:

- a member whose name is absolute, has a drive or a ``..`` component, or which is a symbolic
  link, is refused (:func:`check_archive`): nothing is extracted, but such an entry has no
  business in a capture or a table, and a tool that extracts the archive later would follow it;
- a member or image whose size, declared (zip directory, ``.npy`` or image header) or actual
  (counted while decompressing), exceeds :func:`size_budget` is refused before the memory is
  allocated: a decompression bomb (a few kB that inflate to gigabytes) stops at the budget.

The budget is :data:`MAX_BYTES` (1 GiB: a UBO2003 image is a few MB, a table 79 kB, the largest
prior a few hundred MB), or the number of bytes in the environment variable :data:`BUDGET_ENV`.
Every refusal is an :class:`~abrdf_jax.InputError` naming the file, the member and the budget.
"""

from __future__ import annotations

import os
import stat
import zipfile
from pathlib import PurePosixPath

import numpy as np

from .._errors import InputError, located

#: The most bytes one archive member or one decoded image may hold (override: :data:`BUDGET_ENV`).
MAX_BYTES = 1 << 30
#: Environment variable that overrides :data:`MAX_BYTES` (a whole number of bytes).
BUDGET_ENV = "ABRDF_MAX_MEMBER_BYTES"


def size_budget() -> int:
    """The size budget in bytes: ``$ABRDF_MAX_MEMBER_BYTES`` when set, else :data:`MAX_BYTES`."""
    text = os.environ.get(BUDGET_ENV, "").strip()
    if not text:
        return MAX_BYTES
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise InputError(f"{BUDGET_ENV}={text!r}: expected a whole number of bytes >= 1")
    return value


_UNITS = (("TiB", 40), ("GiB", 30), ("MiB", 20))


def _human(n: int) -> str:
    """``n`` bytes in TiB, GiB or MiB (the largest unit that leaves at least 1; else MiB)."""
    unit, shift = next(((u, s) for u, s in _UNITS if n >= 1 << s), _UNITS[-1])
    return f"{n / (1 << shift):.4g} {unit}"


def check_size(n_bytes: int, what: str, where, budget: int | None = None) -> None:
    """Refuse ``what`` (at ``where``) when its declared size ``n_bytes`` exceeds the budget."""
    budget = size_budget() if budget is None else budget
    if n_bytes > budget:
        raise located(
            f"{what} declares {n_bytes} bytes ({_human(n_bytes)}), over the size budget of "
            f"{budget} bytes ({_human(budget)}; raise it with {BUDGET_ENV})",
            where,
        )


def unsafe_name(name: str) -> str | None:
    """Why the member name ``name`` points outside its archive, or ``None`` when it does not."""
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        return "an absolute path"
    if ".." in PurePosixPath(name.replace("\\", "/")).parts:
        return "a path with '..' (outside the archive)"
    return None


def check_archive(zf: zipfile.ZipFile, where) -> None:
    """Refuse an archive holding a member with an unsafe name, a symbolic link, or a member
    whose declared uncompressed size exceeds the budget (all members, before any is read)."""
    budget = size_budget()
    for info in zf.infolist():
        why = unsafe_name(info.filename)
        if why is None and stat.S_ISLNK(info.external_attr >> 16):
            why = "a symbolic link"
        if why is not None:
            raise located(f"member {info.filename!r} is {why}; refused (nothing extracted)", where)
        check_size(info.file_size, f"member {info.filename!r}", where, budget)


def read_member(zf: zipfile.ZipFile, name: str, where) -> bytes:
    """The bytes of member ``name``: refused when its declared size exceeds the budget, and
    inflated at most one byte past the budget whatever it declares (``zipfile`` itself stops at
    the declared size and reports a member that inflates beyond it as a CRC error)."""
    budget = size_budget()
    info = zf.getinfo(name)
    check_size(info.file_size, f"member {name!r}", where, budget)
    with zf.open(info) as f:
        data = f.read(budget + 1)
    if len(data) > budget:
        raise located(
            f"member {name!r} inflates past the size budget of {budget} bytes ({_human(budget)}; "
            f"raise it with {BUDGET_ENV})",
            where,
        )
    return data


def npy_header(f, what: str, where):
    """``(shape, fortran_order, dtype)`` from the header of the ``.npy`` stream ``f``."""
    version = np.lib.format.read_magic(f)
    if version not in ((1, 0), (2, 0), (3, 0)):
        raise located(f"{what}: unknown .npy format version {version}", where)
    read = getattr(np.lib.format, f"read_array_header_{version[0]}_0")
    return read(f)


def check_npz(path, budget: int | None = None) -> None:
    """Check an ``.npz`` archive before ``np.load`` reads it: :func:`check_archive`, then each
    array's header: its declared data size must fit the budget and its member (``np.load``
    allocates what the header declares before reading the data), and object arrays (pickles)
    are refused.

    Raises:
        InputError: naming ``path`` and the member. ``zipfile.BadZipFile`` passes through (the
            caller says what a corrupt file is for it).
    """
    budget = size_budget() if budget is None else budget
    with zipfile.ZipFile(path) as zf:
        check_archive(zf, path)
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            what = f"array {info.filename.removesuffix('.npy')!r}"
            with zf.open(info) as f:
                shape, _, dtype = npy_header(f, what, path)
                header_bytes = f.tell()
            if dtype.hasobject:
                raise located(f"{what} holds Python objects (a pickle); refused", path)
            n = int(np.prod(shape, dtype=object)) * dtype.itemsize
            check_size(n, what, path, budget)
            if n > info.file_size - header_bytes:
                raise located(
                    f"{what} declares shape {tuple(shape)} ({n} bytes of {dtype}), but its member "
                    f"holds {max(info.file_size - header_bytes, 0)} (truncated or forged)",
                    path,
                )
