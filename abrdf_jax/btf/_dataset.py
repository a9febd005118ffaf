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
import sys
import time
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..io import atomic_write
from ._generate import GENERATOR_VERSION, measurement_geometry, procedural_btf, texel_chunk
from ._store import ChunkedStore

MEASUREMENTS = "measurements"
REFERENCE = "reference"


def _root_stores(root: Path) -> tuple[Path, Path]:
    return root / MEASUREMENTS, root / REFERENCE


def generate_btf(out_dir, size: int, seed: int = 0, *, chunk: int = 1024, reference: bool = True,
                 reference_dtype: str = "float16", progress: bool = False, overwrite: bool = False,
                 maps: bool = True) -> dict[str, Path]:
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
    root = Path(out_dir)
    if not root.parent.is_dir():
        raise InputError(f"{root}: parent folder {root.parent} does not exist")
    root.mkdir(exist_ok=True)
    btf = procedural_btf(size, seed)
    attrs = dict(source="procedural", generator="abrdf_jax.btf.procedural_btf",
                 generator_version=GENERATOR_VERSION, size=btf.size, seed=int(seed))
    texel_shape = (btf.size, btf.size)
    m_path, r_path = _root_stores(root)
    meas = ChunkedStore.create(m_path, kind="measurements", texel_shape=texel_shape, item_shape=(204, 3),
                               dtype="float32", chunk=chunk, geometry=measurement_geometry(), attrs=attrs,
                               overwrite=overwrite)
    ref = None
    if reference:
        ref = ChunkedStore.create(r_path, kind="abrdf", texel_shape=texel_shape, item_shape=(81 * 81, 3),
                                  dtype=reference_dtype, chunk=chunk,
                                  geometry=dict(grid="UBO2003-81", order="i*81+v",
                                                value="BRDF*cos(theta_i), linear RGB"),
                                  attrs=dict(attrs, role="ground truth"), overwrite=overwrite)
    from tqdm import tqdm

    todo = [k for k in range(meas.n_chunks)
            if not meas.is_done(k) or (ref is not None and not ref.is_done(k))]
    parts: dict[str, list] = {}
    with tqdm(total=btf.n_texels, unit="texel", desc="btf generate", disable=not progress,
              file=sys.stderr, dynamic_ncols=True) as bar:
        bar.update(btf.n_texels - sum(b - a for a, b in (meas.chunk_range(k) for k in todo)))
        for k in range(meas.n_chunks):
            a, b = meas.chunk_range(k)
            if k in todo:
                out = texel_chunk(btf, a, b, reference=ref is not None, maps=maps, pad_to=meas.chunk)
                meas.write_chunk(k, out["measurements"])
                if ref is not None:
                    ref.write_chunk(k, out["reference"])
                bar.update(b - a)
            elif maps:  # resumed: the chunk's data exist, its maps do not
                out = texel_chunk(btf, a, b, reference=False, measure=False, maps=True, pad_to=meas.chunk)
            for key, v in out.items() if maps else ():
                if key.startswith("map_"):
                    parts.setdefault(key[4:], []).append(v)
    maps_path = None
    if maps:
        maps_path = root / "maps.npz"
        arrays = {k: np.concatenate(v).reshape(btf.size, btf.size, *v[0].shape[1:]) for k, v in parts.items()}
        with atomic_write(maps_path, "wb") as f:
            np.savez_compressed(f, **arrays)
    doc = dict(attrs, measurements=MEASUREMENTS, reference=REFERENCE if reference else None,
               maps="maps.npz" if maps else None, created=time.strftime("%Y-%m-%d %H:%M:%S"))
    with atomic_write(root / "btf.json", "w") as f:
        json.dump(doc, f, indent=1)
    return {"measurements": m_path, "reference": r_path if reference else None, "maps": maps_path}


def measurement_store_of(path) -> Path:
    """A measurement store folder, or a generated BTF folder holding one in ``measurements/``."""
    p = Path(path)
    if (p / "manifest.json").is_file():
        return p
    if (p / MEASUREMENTS / "manifest.json").is_file():
        return p / MEASUREMENTS
    raise InputError(f"{p}: neither a measurement store nor a BTF folder with {MEASUREMENTS}/manifest.json")
