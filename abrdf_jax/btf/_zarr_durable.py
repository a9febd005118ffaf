"""A zarr ``LocalStore`` whose writes are durable: each key (a chunk or a ``zarr.json``) goes
through :func:`abrdf_jax.io.atomic_write`, so it is written to a temporary file beside its name,
flushed, ``fsync``-ed, renamed onto its name and the folder ``fsync``-ed.

zarr's own ``LocalStore`` renames without ``fsync``: after a power cut a chunk file can exist
under its name with no data behind it. A zarr store's chunk counts as done when its file exists
(and, verified, decodes with a matching crc32c), so here the name appears only once the bytes
are on disk, as the ``.npy`` store's marker does. The cost is one ``fsync`` of the file and one
of its folder per chunk (the same as the ``.npy`` store's data file), plus one per folder this
write creates. Temporary files follow ``atomic_write``'s naming (``.NAME.PID.XXXXXXXX.tmp``):
no zarr key looks like one, and a killed writer's are removed by the next writer's output lock
or by ``ZarrStore.remove_temporary``. ``set_if_not_exists`` (zarr's implicit parent groups,
which a store's flat group never needs) stays zarr's own. Imported only with the ``[zarr]``
extra.
"""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

from zarr.core.buffer import Buffer
from zarr.storage import LocalStore

from ..io._atomic import _fsync_folder, atomic_write


def _make_folders(folder: Path) -> None:
    """``folder`` and its missing parents, each new entry made durable in its parent."""
    missing = []
    while not folder.is_dir():
        missing.append(folder)
        folder = folder.parent
    for f in reversed(missing):
        f.mkdir(exist_ok=True)
        _fsync_folder(f.parent)


def _put(path: Path, data) -> None:
    _make_folders(path.parent)
    with atomic_write(path, "wb", drop_cache=True) as f:  # streamed chunks: not read again soon
        f.write(data)


class DurableLocalStore(LocalStore):
    """``LocalStore`` with ``set`` through :func:`atomic_write` (fsync before the rename)."""

    async def set(self, key: str, value: Buffer) -> None:
        await self._ensure_open()  # as LocalStore.set: makes the root folder
        if self.read_only:
            raise ValueError(f"{self.root}: store opened read-only")
        if not isinstance(value, Buffer):
            raise TypeError(f"DurableLocalStore.set: value must be a Buffer, got {type(value)}")
        path = Path(os.fspath(self.root)) / key
        await asyncio.to_thread(_put, path, value.as_buffer_like())
