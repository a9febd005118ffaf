"""Write a procedural BTF to disk: measurement store, dense reference store, parameter maps.

Folder layout made by :func:`generate_btf` (and ``abrdf-jax btf generate``)::

    DIR/btf.json          what was generated (size, seed, generator version, stores)
    DIR/measurements/     chunked store, (texels, 204, 3) float32, the aniso204 slice samples
    DIR/reference/        chunked store, (texels, 6561, 3), the dense ground truth (optional)
    DIR/maps.npz          per-texel maps (height, normal, class weights, albedo, roughness, ...)

Every chunk is computed from ``(size, seed)`` alone, so generation streams in bounded memory and
resumes like a reconstruction (finished chunks are kept).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..io import atomic_write
from ._generate import GENERATOR_VERSION, measurement_geometry, procedural_btf, texel_chunk
from ._store import ABRDF_GEOMETRY, ChunkedStore, make_folder, progress_bar

MEASUREMENTS = "measurements"
REFERENCE = "reference"


def generate_btf(
    out_dir,
    size: int,
    seed: int = 0,
    *,
    chunk: int = 1024,
    reference: bool = True,
    reference_dtype: str = "float16",
    progress: bool = False,
    overwrite: bool = False,
    maps: bool = True,
) -> dict[str, Path]:
    """Generate a procedural BTF and write its measurements (and dense ground truth).

    Args:
        out_dir: the folder (created; its parent must exist).
        size: texels per side (64 to 256 typical).
        seed: the seed (the same ``(size, seed)`` gives the same bytes).
        chunk: texels per store chunk.
        reference: also write the dense 81×81 ground truth (``size² × 6561 × 3`` values:
            2.6 GB in float16 at 256²).
        reference_dtype: ``"float16"`` or ``"float32"``.
        progress: show a progress bar.
        overwrite: replace stores of a different BTF found in ``out_dir``.
        maps: write ``maps.npz`` with the per-texel parameter maps.

    Returns:
        ``{"measurements": path, "reference": path or None, "maps": path or None}``.
    """
    btf = procedural_btf(size, seed)  # checks size and seed before the folder is made
    root = make_folder(out_dir)
    attrs = dict(source="procedural", generator="abrdf_jax.btf.procedural_btf")
    attrs.update(generator_version=GENERATOR_VERSION, size=btf.size, seed=int(seed))
    n, shape = btf.n_texels, (btf.size, btf.size)
    m_path, r_path = root / MEASUREMENTS, root / REFERENCE
    common = dict(texel_shape=shape, chunk=chunk, overwrite=overwrite)
    kw = dict(geometry=measurement_geometry(), attrs=attrs, **common)
    meas = ChunkedStore.create(
        m_path, kind="measurements", item_shape=(204, 3), dtype="float32", **kw
    )
    stores = [meas]
    if reference:
        kw = dict(geometry=ABRDF_GEOMETRY, attrs=dict(attrs, role="ground truth"), **common)
        ref = ChunkedStore.create(
            r_path, kind="abrdf", item_shape=(81 * 81, 3), dtype=reference_dtype, **kw
        )
        stores.append(ref)
    todo = [k for k in range(meas.n_chunks) if not all(s.is_done(k) for s in stores)]
    parts: dict[str, list] = {}
    pad = meas.chunk
    with progress_bar("btf generate", n, progress, initial=n - meas.texels(todo)) as bar:
        for k in range(meas.n_chunks):
            a, b = meas.chunk_range(k)
            if k in todo:
                out = texel_chunk(btf, a, b, reference=reference, maps=maps, pad_to=pad)
                for store, key in zip(stores, ("measurements", "reference")):
                    store.write_chunk(k, out[key])
                bar.update(b - a)
            elif maps:  # resumed: the chunk's data exist, its maps do not
                out = texel_chunk(btf, a, b, reference=False, measure=False, maps=True, pad_to=pad)
            for key, v in out.items() if maps else ():
                if key.startswith("map_"):
                    parts.setdefault(key[4:], []).append(v)
    maps_path = root / "maps.npz" if maps else None
    if maps:
        arrays = {k: np.concatenate(v).reshape(*shape, *v[0].shape[1:]) for k, v in parts.items()}
        with atomic_write(maps_path, "wb") as f:
            np.savez_compressed(f, **arrays)
    doc = dict(attrs, measurements=MEASUREMENTS, reference=REFERENCE if reference else None)
    doc.update(maps="maps.npz" if maps else None, created=time.strftime("%Y-%m-%d %H:%M:%S"))
    with atomic_write(root / "btf.json", "w") as f:
        json.dump(doc, f, indent=1)
    return {"measurements": m_path, "reference": r_path if reference else None, "maps": maps_path}


def measurement_store_of(path) -> Path:
    """A measurement store folder, or a generated BTF folder holding one in ``measurements/``."""
    p = Path(path)
    for store in (p, p / MEASUREMENTS):
        if (store / "manifest.json").is_file():
            return store
    raise InputError(
        f"{p}: neither a measurement store nor a BTF folder with {MEASUREMENTS}/manifest.json"
    )
