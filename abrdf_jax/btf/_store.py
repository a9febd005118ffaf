"""A chunked array store for per-texel data: a folder, a JSON manifest, one ``.npy`` per chunk.

Layout of a store folder::

    manifest.json          what the store holds (see below); written once, atomically
    chunks/c000000.npy     texels [0, chunk) of the array, a plain NumPy file
    chunks/c000000.json    the chunk's completion marker: range, shape, dtype, byte count, CRC-32C
    chunks/c000001.npy ...

The array has shape ``(n_texels, *item_shape)``, texels numbered row-major over the texture
(``texel_shape = (rows, columns)``): measurements ``(n, n_samples, 3)`` with the sample geometry
(angles per sample) in the manifest, reconstructions ``(n, 6561, 3)`` on the UBO2003 pairs
(``table[i, v]`` flattened ``i * 81 + v``).

Crash safety: a chunk is written to a temporary file beside it, flushed, ``fsync``-ed and renamed
onto its name; only then is its marker written the same way. A chunk counts as done only when
its marker exists, agrees with the manifest (range, shape, dtype) and with the file (byte count,
and with ``verify`` its checksum, :mod:`._checksum`). A crash at any point leaves either no file,
a stray temporary file, or a chunk without marker: none of them looks valid, and a rerun rewrites
the chunk.
Before a chunk is rewritten its old marker is removed first.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._names import STORE_DTYPES as DTYPES
from ..io import atomic_write
from ._checksum import checksum, matches
from ._chunked import ChunkIndex

FORMAT = "abrdf_jax.btf-store"
VERSION = 1
KINDS = ("measurements", "abrdf")
MANIFEST = "manifest.json"
CHUNKS = "chunks"
CORRUPT = "checksum mismatch (corrupt data)"
#: The per-sample angle keys of a measurement geometry (degrees).
ANGLES = ("theta_i", "phi_i", "theta_v", "phi_v")
#: The geometry of an ``"abrdf"`` store: the 81 × 81 UBO2003 pairs.
ABRDF_GEOMETRY = dict(grid="UBO2003-81", order="i*81+v", value="BRDF*cos(theta_i), linear RGB")


def _ours(name: str) -> bool:
    """What another process creating the same store may have put there before its manifest
    (several hosts start one job on one shared folder)."""
    return name == CHUNKS or (name.startswith(f".{MANIFEST}.") and name.endswith(".tmp"))


def make_folder(path) -> Path:
    """The folder ``path``, created if needed (its parent must exist)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError(f"{path}: parent folder {path.parent} does not exist")
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a folder")
    path.mkdir(exist_ok=True)
    return path


def pad_rows(x, n: int) -> np.ndarray:
    """``x`` with its last row repeated up to ``n`` rows: one shape per batch, one compilation."""
    x = np.asarray(x)
    return x if len(x) >= n else np.concatenate([x, np.repeat(x[-1:], n - len(x), axis=0)])


#: Unsigned view, magnitude mask and exponent bits (all set: infinite or NaN) of a store's floats.
_FLOAT_BITS = {
    np.dtype(np.float16): (np.uint16, 0x7FFF, 0x7C00),
    np.dtype(np.float32): (np.uint32, 0x7FFFFFFF, 0x7F800000),
}

_FINITE_BLOCK = 1 << 18


def stored_chunk(path, k: int, start: int, values: np.ndarray, dtype) -> np.ndarray:
    """``values`` of chunk ``k`` (first texel ``start``) as the store's contiguous ``dtype``.

    Raises:
        InputError: (a store never holds them; nothing of the chunk is written) finite values
            beyond the store's float16 range (65504: ``--dtype float32`` stores them), or NaN
            or infinite values (the reconstruction is not finite there, as
            :func:`abrdf_jax.reconstruct`'s checks report it for one material).
    """
    with np.errstate(over="ignore", invalid="ignore"):  # reported below, with the texel
        arr = np.ascontiguousarray(values, dtype=dtype)
    if all_finite(arr):
        return arr
    bad = int(np.argwhere(~np.isfinite(arr))[0][0]) + start
    if np.dtype(dtype) == np.float16 and all_finite(np.asarray(values)):
        top = float(np.max(np.abs(values)))
        raise InputError(
            f"{path}: chunk {k} has values up to {top:.3g}, beyond float16's range (65504; "
            f"first at texel {bad}): store float32 (--dtype float32, Python dtype='float32')"
        )
    raise InputError(
        f"{path}: chunk {k}: the reconstruction holds NaN or infinite values (first at texel "
        f"{bad}); the chunk is not written"
    )


def all_finite(arr: np.ndarray) -> bool:
    """Whether every value of ``arr`` is finite; for float16/float32 one integer pass over the
    bits (the magnitude is below the all-ones exponent), several times faster than numpy's
    float16 ``isfinite``."""
    bits = _FLOAT_BITS.get(arr.dtype)
    if bits is None or not arr.flags.c_contiguous or arr.size == 0:
        return bool(np.isfinite(arr).all())
    kind, magnitude, exponent = bits
    flat, mask = arr.reshape(-1).view(kind), kind(magnitude)
    tmp = np.empty(min(flat.size, _FINITE_BLOCK), kind)  # stays in cache
    for a in range(0, flat.size, _FINITE_BLOCK):
        part = tmp[: min(_FINITE_BLOCK, flat.size - a)]
        np.bitwise_and(flat[a : a + _FINITE_BLOCK], mask, out=part)
        if part.max() >= exponent:
            return False
    return True


def progress_bar(desc: str, total: int, enabled: bool, **kw):
    """The tqdm bar of a streamed job (on stderr; ``kw``: ``unit`` (default texel), ``initial``)."""
    from tqdm import tqdm

    kw.setdefault("unit", "texel")
    return tqdm(
        total=total, desc=desc, disable=not enabled, file=sys.stderr, dynamic_ncols=True, **kw
    )


class ChunkedStore(ChunkIndex):
    """A chunked per-texel array on disk (see the module docstring for the layout).

    Open one with :meth:`open` or make one with :meth:`create`; read with :meth:`read_chunk`,
    :meth:`read` or iterate :meth:`chunk_ranges`; write with :meth:`write_chunk`. The manifest's
    facts are attributes: ``kind``, ``texel_shape`` ``(rows, columns)``, ``n_texels``,
    ``item_shape``, ``shape``, ``dtype``, ``chunk`` (texels per chunk), ``n_chunks``,
    ``geometry``, ``attrs``.
    """

    def _files(self, k: int) -> tuple[Path, Path]:
        base = self.path / CHUNKS / f"c{k:06d}"
        return base.with_suffix(".npy"), base.with_suffix(".json")

    def __repr__(self) -> str:
        return (
            f"ChunkedStore({str(self.path)!r}, kind={self.kind!r}, shape={self.shape}, "
            f"dtype={self.dtype.name}, chunk={self.chunk})"
        )

    # ---------------------------------------------------------------- create / open

    @classmethod
    def create(
        cls,
        path,
        *,
        kind: str,
        texel_shape,
        item_shape,
        dtype="float32",
        chunk: int = 1024,
        geometry: dict | None = None,
        attrs: dict | None = None,
        overwrite: bool = False,
    ) -> "ChunkedStore":
        """Make a store, or reopen the same one (for a resumed run).

        If ``path`` already holds a store with the same manifest it is reopened as it is (its
        finished chunks stay). A store with a different manifest is an error unless
        ``overwrite``, which removes its chunks first.

        Args:
            path: the folder (created; its parent must exist).
            kind: ``"measurements"`` or ``"abrdf"``.
            texel_shape: ``(rows, columns)`` of the texture.
            item_shape: shape per texel, e.g. ``(204, 3)`` or ``(6561, 3)``.
            dtype: ``"float16"`` or ``"float32"``.
            chunk: texels per chunk.
            geometry: the sample directions (measurements) or the grid (reconstructions).
            attrs: anything else JSON-serialisable (provenance, the settings of the run).
            overwrite: replace a different store found at ``path``.

        Raises:
            InputError: bad arguments, a parent folder that does not exist, a non-store folder
                that is not empty, or a different store without ``overwrite``.
        """
        if kind not in KINDS:
            raise InputError(f"store kind must be one of {KINDS}, got {kind!r}")
        dtype = np.dtype(dtype).name
        if dtype not in DTYPES:
            raise InputError(f"store dtype must be one of {DTYPES}, got {dtype!r}")
        texel_shape = [int(x) for x in texel_shape]
        if len(texel_shape) != 2 or min(texel_shape) < 1:
            raise InputError(f"texel_shape must be (rows, columns) >= 1, got {texel_shape}")
        if not isinstance(chunk, (int, np.integer)) or chunk < 1:
            raise InputError(f"chunk must be a positive integer, got {chunk!r}")
        manifest = dict(format=FORMAT, version=VERSION, kind=kind, texel_shape=texel_shape)
        manifest.update(item_shape=[int(x) for x in item_shape], dtype=dtype, chunk=int(chunk))
        manifest.update(geometry=geometry or {}, attrs=attrs or {})
        manifest = json.loads(json.dumps(manifest))  # normalise (tuples -> lists, numpy -> float)
        path = make_folder(path)
        if (path / MANIFEST).exists():
            old = cls.open(path)
            if old.manifest != manifest and not overwrite:
                raise InputError(
                    f"{path}: holds a different {old.kind} store (other data or settings); "
                    "choose another folder or overwrite it"
                )
            if old.manifest == manifest:
                (path / CHUNKS).mkdir(exist_ok=True)
                return old
            old.remove_chunks()
        elif any(not _ours(p.name) for p in path.iterdir()):
            raise InputError(f"{path}: folder is not empty and holds no store ({MANIFEST} missing)")
        (path / CHUNKS).mkdir(exist_ok=True)
        with atomic_write(path / MANIFEST, "w") as f:
            json.dump(manifest, f, indent=1)
        return cls(path, manifest)

    @classmethod
    def open(cls, path) -> "ChunkedStore":
        """Open an existing store.

        Raises:
            InputError: no store at ``path`` or an unreadable or foreign manifest.
        """
        mf = Path(path) / MANIFEST
        if not mf.is_file():
            raise InputError(f"{path}: not a chunked store ({MANIFEST} not found)")
        try:
            manifest = json.loads(mf.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            raise InputError(f"{mf}: cannot read the manifest: {e}") from e
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            raise InputError(f"{mf}: not an {FORMAT} manifest")
        if manifest.get("version") != VERSION:
            raise InputError(
                f"{mf}: store version {manifest.get('version')!r}; this reader knows {VERSION}"
            )
        try:
            return cls(path, manifest)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{mf}: manifest lacks or garbles {e}") from e

    def _remove(self, prefixes, suffixes) -> int:
        folder = self.path / CHUNKS
        names = os.listdir(folder) if folder.is_dir() else []
        n = 0
        for name in sorted(names, key=lambda n: not n.endswith(".json")):  # markers first
            if name.startswith(prefixes) and name.endswith(suffixes):
                with contextlib.suppress(FileNotFoundError):
                    (folder / name).unlink()
                    n += 1
        return n

    def remove_chunks(self) -> None:
        """Delete every chunk, marker and stray temporary file (markers first)."""
        self._remove(("c", ".c"), (".npy", ".json", ".tmp"))

    def remove_temporary(self) -> int:
        """Delete stray temporary files of interrupted writes; returns how many.

        Only safe when no other process writes to this store at the same time.
        """
        return self._remove(".c", ".tmp")

    # ---------------------------------------------------------------- chunks

    def _expected_marker(self, k: int) -> dict:
        a, b = self.chunk_range(k)
        return dict(
            index=k, start=a, stop=b, shape=[b - a, *self.item_shape], dtype=self.dtype.name
        )

    def _marker(self, k: int) -> dict | None:
        _, marker = self._files(k)
        try:
            m = json.loads(marker.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return m if isinstance(m, dict) else None

    def _unverified(self, k: int) -> tuple[str, dict | None]:
        """:meth:`chunk_status` without the checksum, and the marker it read (once)."""
        data, _ = self._files(k)
        m = self._marker(k)
        if m is None:
            return "missing", None
        exp = self._expected_marker(k)
        if any(m.get(key) != val for key, val in exp.items()):
            return "marker disagrees with the manifest", m
        try:
            size = data.stat().st_size
        except OSError:
            return "data file missing", m
        if size != m.get("bytes"):
            return f"data file has {size} bytes, marker says {m.get('bytes')}", m
        return "done", m

    def chunk_status(self, k: int, verify: bool = True) -> str:
        """``"done"``, ``"missing"`` (never finished) or why the chunk is not valid."""
        status, m = self._unverified(k)
        if status == "done" and verify and not matches(m, self._files(k)[0].read_bytes()):
            return CORRUPT
        return status

    def write_chunk(self, k: int, values) -> None:
        """Write chunk ``k`` atomically, then its marker.

        Args:
            k: chunk index.
            values: ``(stop - start, *item_shape)``; cast to the store dtype.

        Raises:
            ValueError: wrong shape.
            InputError: values that are NaN or infinite, also after the cast (a float16
                overflow): a store never holds them (:func:`stored_chunk`).
        """
        start, stop = self.chunk_range(k)
        arr = np.asarray(values)
        want = (stop - start, *self.item_shape)
        if arr.shape != want:
            raise ValueError(f"{self.path}: chunk {k} has shape {arr.shape}, expected {want}")
        arr = stored_chunk(self.path, k, start, arr, self.dtype)
        # The .npy header, then the array's own memory: no serialised copy of the chunk.
        head = io.BytesIO()
        np.lib.format.write_array_header_1_0(head, np.lib.format.header_data_from_array_1_0(arr))
        header, body = head.getvalue(), memoryview(arr).cast("B")
        data, marker = self._files(k)
        with contextlib.suppress(FileNotFoundError):
            marker.unlink()  # the chunk is invalid from now until the new marker lands
        with atomic_write(data, "wb", drop_cache=True) as f:  # streamed: not read again soon
            f.write(header)
            f.write(body)
        meta = self._expected_marker(k)
        meta.update(bytes=len(header) + len(body), **checksum(header, body))
        with atomic_write(marker, "w") as f:
            json.dump(meta, f)

    def read_chunk(self, k: int, verify: bool = True) -> np.ndarray:
        """Chunk ``k`` as an array ``(stop - start, *item_shape)``.

        Raises:
            InputError: the chunk is missing or invalid (the message says why).
        """
        data, _ = self._files(k)
        status, marker = self._unverified(k)
        raw = data.read_bytes() if status == "done" else b""
        if verify and status == "done" and not matches(marker, raw):
            status = CORRUPT
        if status != "done":
            raise InputError(f"{data}: chunk {k} of {self.path} is not valid: {status}")
        try:
            arr = np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
        except Exception as e:  # noqa: BLE001 - numpy raises several types on a bad header
            raise InputError(f"{data}: cannot read chunk {k}: {e}") from e
        start, stop = self.chunk_range(k)
        if arr.shape != (stop - start, *self.item_shape) or arr.dtype != self.dtype:
            raise InputError(
                f"{data}: chunk {k} holds {arr.dtype}{arr.shape}, manifest says otherwise"
            )
        return arr

    def read(self, start: int = 0, stop: int | None = None, verify: bool = True) -> np.ndarray:
        """Texels ``[start, stop)`` (across chunks) as one array."""
        stop = self.n_texels if stop is None else stop
        if not 0 <= start <= stop <= self.n_texels:
            raise InputError(f"{self.path}: texel range {start}:{stop} outside 0:{self.n_texels}")
        c = self.chunk
        parts = [
            self.read_chunk(k, verify)[max(start - k * c, 0) : stop - k * c]
            for k in range(start // c, -(-stop // c))
        ]
        if len(parts) == 1:
            return parts[0]
        return np.concatenate(parts) if parts else np.zeros((0, *self.item_shape), self.dtype)
