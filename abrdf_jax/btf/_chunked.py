"""What every per-texel chunk store shares, whatever holds its chunks: the manifest's facts, the
texel range of each chunk, and the bookkeeping built on a store's ``chunk_status(k, verify)``
(``"done"`` or why not). ``ChunkedStore`` (``.npy`` files) and ``ZarrStore`` (a zarr v3 group)
are its two kinds (``abrdf_jax.btf._backend``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


class ChunkIndex:
    """The manifest's facts as attributes: ``kind``, ``texel_shape`` ``(rows, columns)``,
    ``n_texels``, ``item_shape``, ``shape``, ``dtype``, ``chunk`` (texels per chunk),
    ``n_chunks``, ``geometry``, ``attrs``; subclasses define ``chunk_status``."""

    def __init__(self, path: Path, manifest: dict):
        self.path, self.manifest = Path(path), manifest
        self.kind = manifest["kind"]
        self.texel_shape = tuple(int(x) for x in manifest["texel_shape"])
        self.item_shape = tuple(int(x) for x in manifest["item_shape"])
        self.dtype = np.dtype(manifest["dtype"])
        self.chunk = int(manifest["chunk"])
        self.geometry = manifest.get("geometry", {})
        self.attrs = manifest.get("attrs", {})
        self.n_texels = self.texel_shape[0] * self.texel_shape[1]
        self.shape = (self.n_texels, *self.item_shape)
        self.n_chunks = -(-self.n_texels // self.chunk)

    def chunk_range(self, k: int) -> tuple[int, int]:
        """Texel range ``[start, stop)`` of chunk ``k``."""
        if not 0 <= k < self.n_chunks:
            raise IndexError(f"{self.path}: chunk {k} out of range 0..{self.n_chunks - 1}")
        return k * self.chunk, min((k + 1) * self.chunk, self.n_texels)

    def chunk_ranges(self) -> list[tuple[int, int]]:
        return [self.chunk_range(k) for k in range(self.n_chunks)]

    def texels(self, chunks) -> int:
        """How many texels the chunks ``chunks`` hold."""
        return sum(b - a for a, b in map(self.chunk_range, chunks))

    def chunk_status(self, k: int, verify: bool = True) -> str:
        raise NotImplementedError

    def finish(self) -> None:
        """What a store does once its writer has written every chunk it owns (the zarr store
        consolidates its metadata when complete); nothing here."""

    def is_done(self, k: int, verify: bool = True) -> bool:
        return self.chunk_status(k, verify) == "done"

    def done_chunks(self, verify: bool = True) -> list[int]:
        """Indices of the valid chunks (``verify`` also checks every checksum)."""
        return [k for k in range(self.n_chunks) if self.is_done(k, verify)]

    @property
    def complete(self) -> bool:
        return all(self.is_done(k, verify=False) for k in range(self.n_chunks))

    def verify(self) -> dict[int, str]:
        """``{chunk: problem}`` for every chunk that is not done (empty when all are valid)."""
        return {
            k: s for k in range(self.n_chunks) if (s := self.chunk_status(k, verify=True)) != "done"
        }
