"""The zarr v3 backend of the chunked ABRDF store (``pip install abrdf_jax[zarr]``).

Layout of a group folder (read by ``xarray.open_zarr``, ``dask.array.from_zarr``, napari)::

    zarr.json          group; attribute ``abrdf_jax``: the manifest a ChunkedStore keeps
                       (format, kind, texel_shape, item_shape, dtype, chunk, geometry, attrs)
    abrdf/             (y, x, light, view, rgb) float16/float32, one chunk = one band of texel
                       rows (or of one row), codecs bytes + crc32c; fill value NaN (never stored)
    theta_light/ phi_light/ theta_view/ phi_view/   the 81 UBO2003 directions (degrees)
    light/ view/ y/ x/ rgb/                         index coordinates

Chunk ``k`` holds texels ``[k * chunk, (k + 1) * chunk)`` in row-major order, as the ``.npy``
store's chunk ``k``: ``chunk`` must be a multiple of the texture width (bands of rows) or divide
it, so every store chunk is exactly one zarr chunk and no two writers share one. Every key is
written to a temporary file, ``fsync``-ed and renamed onto its name (:mod:`._zarr_durable`), so
a chunk's name (what marks it done) appears only once its bytes are on disk; the crc32c codec
catches a chunk damaged later (a bad read raises, naming the chunk's file). :meth:`finish`
consolidates the metadata once every chunk is written.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._grid import ubo_grid
from ..io._atomic import remove_stale_temps
from ._chunked import ChunkIndex
from ._store import CORRUPT, FORMAT, KINDS, VERSION, make_folder, stored_chunk

ARRAY = "abrdf"
DIMS = ("y", "x", "light", "view", "rgb")
ATTR = "abrdf_jax"
COORDS = ("theta_light", "phi_light", "theta_view", "phi_view")


def _zarr():
    try:
        import zarr
        from zarr.codecs import BytesCodec, Crc32cCodec
    except ImportError as e:
        raise InputError("the zarr store format needs zarr>=3: pip install abrdf_jax[zarr]") from e
    return zarr, BytesCodec, Crc32cCodec


def _local_store(path):
    """The group folder as a zarr store whose writes are fsync'ed before their rename."""
    from ._zarr_durable import DurableLocalStore

    return DurableLocalStore(path)


def _writing(array):
    """``array`` set to store every chunk it is given without first comparing it with the fill
    value (``write_empty_chunks``): a store chunk is never all NaN (``write_chunk`` refuses NaN),
    and that comparison cost more than the write itself (about 2x the .npy store's write time
    at 1024 texels per chunk). zarr before 3.1 has no ``with_config``: the array as it is."""
    with_config = getattr(array, "with_config", None)
    return array if with_config is None else with_config({"write_empty_chunks": True})


def is_zarr_store(path) -> bool:
    return (Path(path) / "zarr.json").is_file()


def band(texel_shape, chunk: int) -> tuple[int, int]:
    """The zarr chunk ``(rows, columns)`` of ``chunk`` texels: whole rows or a part of one row."""
    rows, cols = texel_shape
    if chunk >= cols and chunk % cols == 0:
        return min(chunk // cols, rows), cols
    if chunk < cols and cols % chunk == 0:
        return 1, chunk
    raise InputError(
        f"--chunk {chunk}: a zarr store's chunks are tiles of the {rows}x{cols} texture; chunk "
        f"must be a multiple of the width {cols} (bands of rows) or divide it"
    )


class ZarrStore(ChunkIndex):
    """A zarr v3 ABRDF store with the reading and writing interface of ``ChunkedStore``."""

    format = "zarr"

    def __init__(self, path: Path, manifest: dict, group):
        super().__init__(path, manifest)
        self.group = group
        self.tile = band(self.texel_shape, self.chunk)
        self.array = _writing(group[ARRAY])

    def __repr__(self) -> str:
        return f"ZarrStore({str(self.path)!r}, shape={self.shape}, dtype={self.dtype.name})"

    def _index(self, k: int):
        """The zarr chunk coordinates and the (rows, columns) slices of store chunk ``k``."""
        a, b = self.chunk_range(k)
        cols = self.texel_shape[1]
        r0, c0 = divmod(a, cols)
        r1 = r0 + (-(-(b - a) // cols) if self.tile[1] == cols else 1)
        c1 = cols if self.tile[1] == cols else c0 + (b - a)
        coords = (r0 // self.tile[0], c0 // self.tile[1], 0, 0, 0)
        return coords, (slice(r0, r1), slice(c0, c1))

    def chunk_file(self, k: int) -> Path:
        coords, _ = self._index(k)
        return self.path / ARRAY / "c" / "/".join(map(str, coords))

    # ---------------------------------------------------------------- create / open

    @classmethod
    def create(
        cls,
        path,
        *,
        kind,
        texel_shape,
        item_shape,
        dtype="float16",
        chunk=1024,
        geometry=None,
        attrs=None,
        overwrite=False,
    ) -> "ZarrStore":
        """Make a zarr group (or reopen the same one for a resumed run); arguments as
        ``ChunkedStore.create``; only ``kind="abrdf"`` (the 81 x 81 pairs)."""
        zarr, BytesCodec, Crc32cCodec = _zarr()
        if kind != "abrdf" or tuple(item_shape) != (81 * 81, 3):
            raise InputError(f"{path}: the zarr format holds ABRDF stores (6561 x 3 per texel)")
        texel_shape = [int(x) for x in texel_shape]
        tile = band(texel_shape, int(chunk))
        manifest = dict(format=FORMAT, version=VERSION, kind=kind, texel_shape=texel_shape)
        manifest.update(item_shape=[int(x) for x in item_shape], dtype=np.dtype(dtype).name)
        manifest.update(chunk=int(chunk), geometry=geometry or {}, attrs=attrs or {})
        manifest = json.loads(json.dumps(manifest))
        path = make_folder(path)
        if is_zarr_store(path):
            old = cls.open(path)
            if old.manifest == manifest:
                return old
            if not overwrite:
                raise InputError(
                    f"{path}: holds a different zarr store (other data or settings); choose "
                    "another folder or overwrite it"
                )
        elif any(path.iterdir()):
            raise InputError(f"{path}: folder is not empty and holds no zarr store")
        group = zarr.open_group(_local_store(path), mode="w", zarr_format=3)
        arr = group.create_array(
            ARRAY,
            shape=(*texel_shape, 81, 81, 3),
            chunks=(*tile, 81, 81, 3),
            dtype=manifest["dtype"],
            fill_value=np.nan,
            dimension_names=DIMS,
            serializer=BytesCodec(),
            compressors=[Crc32cCodec()],
            filters=None,
        )
        arr.attrs.update(coordinates=" ".join(COORDS), units="BRDF * cos(theta_light), linear RGB")
        theta, phi = ubo_grid()
        for name, dim, values in (
            ("theta_light", "light", theta),
            ("phi_light", "light", phi),
            ("theta_view", "view", theta),
            ("phi_view", "view", phi),
            ("light", "light", np.arange(81)),
            ("view", "view", np.arange(81)),
            ("y", "y", np.arange(texel_shape[0])),
            ("x", "x", np.arange(texel_shape[1])),
            ("rgb", "rgb", np.array([0, 1, 2])),
        ):
            a = group.create_array(
                name, shape=values.shape, dtype=values.dtype, dimension_names=(dim,)
            )
            a[:] = values
            if name.startswith(("theta", "phi")):
                a.attrs.update(units="degree")
        geo = dict(
            azimuth="ccw (PROTOCOL.md)",
            colour_space="linear sRGB primaries",
            cos_weighted=True,
            scale=1.0,
        )
        job = manifest["attrs"].get("job", {})
        geo.update(model=job.get("model"), config=job.get("config"), params=job.get("params"))
        group.attrs.update({ATTR: manifest, **geo, "grid": "UBO2003-81"})  # last: complete
        return cls(path, manifest, group)

    @classmethod
    def open(cls, path) -> "ZarrStore":
        zarr, _, _ = _zarr()
        if not is_zarr_store(path):
            raise InputError(f"{path}: not a zarr store (zarr.json not found)")
        try:
            group = zarr.open_group(_local_store(path), mode="r+")
            manifest = dict(group.attrs[ATTR])
        except Exception as e:  # noqa: BLE001 - zarr raises several types on bad metadata
            raise InputError(f"{path}: cannot open the zarr group: {e}") from e
        if manifest.get("format") != FORMAT or manifest.get("kind") not in KINDS:
            raise InputError(f"{path}: not an {FORMAT} zarr store")
        return cls(path, manifest, group)

    def remove_temporary(self) -> int:
        """Delete the temporary files killed writers left: this store's ``.*.tmp``
        (:mod:`._zarr_durable`) and zarr's own ``*.partial``; one writing process only."""
        n = remove_stale_temps(self.path, locked=True)
        for root, _, files in os.walk(self.path / ARRAY / "c"):
            for f in files:
                if f.endswith(".partial"):
                    os.unlink(os.path.join(root, f))
                    n += 1
        return n

    def finish(self) -> None:
        """Once every chunk is written: consolidate the group's metadata into its ``zarr.json``
        (``xarray.open_zarr`` then opens it with one read, and without its warning). Chunk
        writes leave the metadata as it is, so a recomputed chunk does not outdate it."""
        import warnings

        zarr, _, _ = _zarr()
        if not self.complete:
            return
        with warnings.catch_warnings():  # "not part of the Zarr format 3 specification": known
            warnings.simplefilter("ignore", UserWarning)
            self.group = zarr.consolidate_metadata(self.group.store)
        self.array = _writing(self.group[ARRAY])

    def remove_chunks(self) -> None:
        import shutil

        shutil.rmtree(self.path / ARRAY / "c", ignore_errors=True)

    # ---------------------------------------------------------------- chunks

    def chunk_status(self, k: int, verify: bool = True) -> str:
        if not self.chunk_file(k).is_file():
            return "missing"
        if verify:
            try:
                self.read_chunk(k)
            except InputError as e:
                return str(e).rpartition(": ")[2] or CORRUPT
        return "done"

    def write_chunk(self, k: int, values) -> None:
        """Write chunk ``k`` (``(stop - start, 6561, 3)``) as one zarr chunk key."""
        a, b = self.chunk_range(k)
        arr = np.asarray(values)
        if arr.shape != (b - a, *self.item_shape):
            raise ValueError(f"{self.path}: chunk {k} has shape {arr.shape}")
        arr = stored_chunk(self.path, k, a, arr, self.dtype)
        _, (rows, cols) = self._index(k)
        shape = (rows.stop - rows.start, cols.stop - cols.start, 81, 81, 3)
        self.array[rows, cols] = arr.reshape(shape)

    def read_chunk(self, k: int, verify: bool = True) -> np.ndarray:
        """Chunk ``k`` as ``(stop - start, 6561, 3)``; the crc32c codec checks it."""
        path = self.chunk_file(k)
        if not path.is_file():
            raise InputError(f"{path}: chunk {k} of {self.path} is not valid: missing")
        _, (rows, cols) = self._index(k)
        try:
            arr = np.asarray(self.array[rows, cols])
        except Exception as e:  # noqa: BLE001 - the codec pipeline raises several types
            raise InputError(f"{path}: chunk {k} of {self.path} is not valid: {CORRUPT}") from e
        return arr.reshape(-1, *self.item_shape)

    def read(self, start: int = 0, stop: int | None = None, verify: bool = True) -> np.ndarray:
        stop = self.n_texels if stop is None else stop
        if not 0 <= start <= stop <= self.n_texels:
            raise InputError(f"{self.path}: texel range {start}:{stop} outside 0:{self.n_texels}")
        c = self.chunk
        parts = [
            self.read_chunk(k, verify)[max(start - k * c, 0) : stop - k * c]
            for k in range(start // c, -(-stop // c))
        ]
        return np.concatenate(parts) if parts else np.zeros((0, *self.item_shape), self.dtype)
