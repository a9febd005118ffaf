"""``btf export --zarr``: an ``.npy`` ABRDF store copied into a zarr v3 group, chunk by chunk."""

from __future__ import annotations

import os
from pathlib import Path

from .._errors import InputError
from ..io._atomic import write_error
from ._backend import open_store
from ._store import progress_bar
from ._zarr import ZarrStore


def export_zarr(store, out, *, progress: bool = True, overwrite: bool = False) -> "ZarrStore":
    """Copy a complete ``.npy`` ABRDF store into a new zarr group ``out``, chunk by chunk.

    Memory: one chunk. Atomic: the group is built in a hidden folder beside ``out`` and renamed
    onto it when every chunk is written, so an interrupted export leaves no ``out``.

    Raises:
        InputError: the input is not a complete ABRDF store, or ``out`` exists (and not
            ``overwrite``).
    """
    import shutil

    src = open_store(store, "abrdf", complete=True)
    out = Path(out)
    if out.exists() and not overwrite:
        raise InputError(f"{out}: exists; choose another name or overwrite it")
    tmp = out.parent / f".{out.name}.{os.getpid()}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    kw = dict(texel_shape=src.texel_shape, item_shape=src.item_shape, dtype=src.dtype.name)
    kw.update(chunk=src.chunk, geometry=src.geometry, attrs=src.attrs)
    try:
        dst = ZarrStore.create(tmp, kind="abrdf", **kw)
        with progress_bar("btf export zarr", src.n_texels, progress) as bar:
            for k in range(src.n_chunks):
                dst.write_chunk(k, src.read_chunk(k, verify=True))
                bar.update(src.texels([k]))
        dst.finish()
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, OSError) or isinstance(e.__cause__, OSError):  # full, read-only, ...
            raise write_error(out, e) from e  # name the group, not a file of its hidden copy
        raise
    return ZarrStore.open(out)
