"""Storage backends of the per-texel stores, by format name: one interface, two layouts.

``"npy"`` (:class:`~._store.ChunkedStore`: a manifest and one checksummed ``.npy`` per chunk)
and ``"zarr"`` (:class:`~._zarr.ZarrStore`: a zarr v3 group, optional extra ``[zarr]``). Both
have ``create``/``open``, ``chunk_range``, ``is_done``, ``write_chunk``, ``read_chunk``,
``read``, ``verify`` and ``remove_temporary``, so the reconstruction loop, the readers and the
metrics are written once.
"""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError
from .._names import STORE_FORMATS
from ._store import ChunkedStore


def _zarr_store():
    from ._zarr import ZarrStore

    return ZarrStore


#: format name -> a function returning the store class (zarr imported only when used)
FORMATS = {"npy": lambda: ChunkedStore, "zarr": _zarr_store}
#: the format ``btf reconstruct`` writes without ``--format`` (docs/btf.md says why)
DEFAULT_FORMAT = STORE_FORMATS[0]
assert tuple(FORMATS) == STORE_FORMATS


def store_class(fmt: str):
    if fmt not in FORMATS:
        raise InputError(f"store format must be one of {tuple(FORMATS)}, got {fmt!r}")
    return FORMATS[fmt]()


def format_of(path) -> str:
    """``"zarr"`` for a folder holding a zarr group, else ``"npy"``."""
    return "zarr" if (Path(path) / "zarr.json").is_file() else "npy"


def open_store(store, kind: str | None = None, complete: bool = False):
    """``store`` (a store object or its folder, either format), checked to be of ``kind`` and,
    with ``complete``, to have every chunk (no checksums)."""
    if isinstance(store, (str, Path)):
        store = store_class(format_of(store)).open(store)
    if kind is not None and store.kind != kind:
        raise InputError(f"{store.path}: is a {store.kind} store, expected {kind}")
    bad = [k for k in range(store.n_chunks) if complete and not store.is_done(k, verify=False)]
    if bad:
        raise InputError(
            f"{store.path}: {len(bad)} of {store.n_chunks} chunks missing or invalid "
            f"(first: {bad[0]}); finish it first"
        )
    return store
