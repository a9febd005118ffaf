"""BTFs as one OpenEXR image per direction pair, the layout of the UBO2003 and UTIA databases.

A BTF database stores one rectified image of the sample per (illumination, view) pair. Here a
folder holds one RGB OpenEXR image per pair, named

``tl{θi}_pl{φi}_tv{θv}_pv{φv}.exr``  (angles in degrees, e.g. ``tl075_pl015_tv030_pv120.exr``)

with each angle written as three digits when it is whole (``030``) and with three decimals
otherwise (``014.400``; slice samples lie between grid azimuths). Image row ``r``, column ``c``
is texel ``r * width + c``; values are linear RGB (``BRDF · cos θi``), half or float, ZIP
compressed. A reconstructed BTF is the 81 × 81 = 6561 UBO2003 pairs; a measured one is its slice
samples. ``pairs.json`` beside the images lists the exact angles and the file of each pair (the
reader prefers it to the rounded names, and falls back to the names without it).

Both directions stream in bounded memory: writing gathers groups of pairs from the chunked
store, reading gathers groups of texel rows from the images (each image is decoded once per
group), with the group sizes set by ``memory_limit``.
"""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path

import numpy as np

from .._errors import InputError, located
from .._grid import pair_grid
from .._slices import PROTOCOL_PAIRS
from ..io import atomic_write
from ..io._exr import read_rgb_exr, write_rgb_exr
from ._store import ABRDF_GEOMETRY, ANGLES, ChunkedStore, make_folder, open_store, progress_bar

PAIRS_INDEX = "pairs.json"
_NAME = re.compile(
    r"^tl(\d+(?:\.\d+)?)_pl(\d+(?:\.\d+)?)_tv(\d+(?:\.\d+)?)_pv(\d+(?:\.\d+)?)\.exr$", re.I
)


def _fmt(angle: float) -> str:
    a = float(angle) % 360.0 if float(angle) >= 360.0 else float(angle)
    if abs(a - round(a)) < 1e-9:
        return f"{int(round(a)):03d}"
    return f"{a:07.3f}"


def pair_filename(theta_i: float, phi_i: float, theta_v: float, phi_v: float) -> str:
    """The image name of a direction pair (degrees), e.g. ``tl075_pl015_tv030_pv120.exr``."""
    return f"tl{_fmt(theta_i)}_pl{_fmt(phi_i)}_tv{_fmt(theta_v)}_pv{_fmt(phi_v)}.exr"


def parse_pair_filename(name: str) -> tuple[float, float, float, float] | None:
    """``(θi, φi, θv, φv)`` in degrees from an image name, or ``None`` if it does not match."""
    m = _NAME.match(Path(name).name)
    return None if m is None else tuple(float(g) for g in m.groups())


def write_exr_pairs(
    store,
    folder,
    *,
    half: bool = True,
    compression: str = "zip",
    memory_limit: int = 1 << 30,
    progress: bool = False,
) -> int:
    """Write a chunked store as one EXR image per direction pair (see the module docstring).

    Args:
        store: a :class:`ChunkedStore` or its folder (complete).
        folder: the output folder (created; its parent must exist).
        half: 16-bit float channels (else 32-bit).
        compression: ``"zip"`` (lossless) or ``"none"`` (faster).
        memory_limit: bytes of pair images gathered at a time.
        progress: show a progress bar.

    Returns:
        The number of images written.
    """
    store = open_store(store, complete=True)
    if compression not in ("zip", "none"):
        raise InputError(f"compression must be 'zip' or 'none', got {compression!r}")
    folder = make_folder(folder)
    # the angles (θi, φi, θv, φv in degrees) of the pairs a texel holds
    g = store.geometry
    angles = pair_grid() if store.kind == "abrdf" else [np.asarray(g[k], float) for k in ANGLES]
    pairs, (h, w) = np.stack(angles, axis=1), store.texel_shape
    per_pair = store.n_texels * 3 * store.dtype.itemsize
    group = int(max(1, min(len(pairs), memory_limit // per_pair)))
    names = [pair_filename(*p) for p in pairs]
    if len(set(names)) != len(names):
        raise InputError(
            f"{store.path}: two pairs share an image name; angles too close to tell apart"
        )
    with contextlib.suppress(FileNotFoundError):
        (folder / PAIRS_INDEX).unlink()  # incomplete until the new index lands
    kw = dict(half=half, compression=compression, durable=False)
    with progress_bar("exr export", len(pairs), progress, unit="image") as bar:
        for p0 in range(0, len(pairs), group):
            p1 = min(p0 + group, len(pairs))
            buf = np.empty((p1 - p0, store.n_texels, 3), store.dtype)
            for k in range(store.n_chunks):
                a, b = store.chunk_range(k)
                buf[:, a:b] = store.read_chunk(k, verify=False)[:, p0:p1].transpose(1, 0, 2)
            for j in range(p1 - p0):
                write_rgb_exr(folder / names[p0 + j], buf[j].reshape(h, w, 3), **kw)
                bar.update(1)
    listing = [dict(file=n, **dict(zip(ANGLES, map(float, p)))) for n, p in zip(names, pairs)]
    index = dict(kind=store.kind, texel_shape=[h, w], geometry=g, pairs=listing)
    with atomic_write(folder / PAIRS_INDEX, "w") as f:
        json.dump(index, f)
    return len(pairs)


def _list_pairs(folder: Path) -> tuple[list[Path], np.ndarray, dict]:
    """Image files, their angles ``(P, 4)`` and extra geometry, from pairs.json or the names."""
    index = folder / PAIRS_INDEX
    if index.is_file():
        try:
            doc = json.loads(index.read_text(encoding="utf-8"))
            files = [folder / e["file"] for e in doc["pairs"]]
            angles = np.array([[e[k] for k in ANGLES] for e in doc["pairs"]], float)
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise located(f"cannot read the pair index: {e}", index) from e
        return files, angles, dict(doc.get("geometry") or {})
    # in numeric order of (θi, φi, θv, φv)
    found = sorted((a, p) for p in folder.iterdir() if (a := parse_pair_filename(p.name)))
    if not found:
        raise InputError(
            f"{folder}: no images named like tl030_pl000_tv030_pv000.exr and no {PAIRS_INDEX}"
        )
    return [p for _, p in found], np.array([a for a, _ in found], float), {}


def _match_ubo(angles: np.ndarray) -> np.ndarray | None:
    """Position of each UBO pair among ``angles``, or ``None`` unless they are exactly the 6561."""
    if len(angles) != 81 * 81:
        return None
    grid = np.stack(pair_grid(), axis=1)
    key = lambda a: [tuple(np.round(r, 3)) for r in np.where(np.isclose(a, 360.0), 0.0, a)]  # noqa: E731
    where = {k: i for i, k in enumerate(key(angles))}
    try:
        return np.asarray([where[k] for k in key(grid)])
    except KeyError:
        return None


def read_exr_pairs(
    folder,
    out_store,
    *,
    chunk: int = 1024,
    dtype: str = "float32",
    alpha_deg: float | None = None,
    memory_limit: int = 1 << 30,
    overwrite: bool = False,
    progress: bool = False,
) -> ChunkedStore:
    """Read a folder of per-pair EXR images into a chunked store.

    The exact 6561 UBO2003 pairs make an ``"abrdf"`` store (in ``table[i, v]`` order); any other
    set of pairs makes a ``"measurements"`` store whose geometry is the pairs' angles (α read
    from ``pairs.json``, given, or estimated from the angles).

    Args:
        folder: the image folder.
        out_store: the store folder to create.
        chunk: texels per chunk.
        dtype: store dtype.
        alpha_deg: slice offset of a measurement (default: ``pairs.json`` or estimated).
        memory_limit: bytes of texel rows gathered at a time.
        overwrite: replace a different store at ``out_store``.
        progress: show a progress bar.

    Raises:
        InputError: no images, images of different sizes, unreadable images.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    files, angles, geometry = _list_pairs(folder)
    for f in files:
        if not f.is_file():
            raise InputError(f"{f}: listed in {PAIRS_INDEX} but missing")
    order = _match_ubo(angles)
    if order is not None:
        files, kind, geo = [files[i] for i in order], "abrdf", ABRDF_GEOMETRY
    else:
        from .._grouping import estimate_alpha
        from .._measurements import Samples
        from .._pipeline import infer_budget

        samples = Samples(*angles.T, np.zeros((len(angles), 3)))
        alpha = geometry.get("alpha_deg") if alpha_deg is None else alpha_deg
        alpha = float(round(float(estimate_alpha(samples)), 3) if alpha is None else alpha)
        kind, geo = "measurements", {k: angles[:, j].tolist() for j, k in enumerate(ANGLES)}
        budget = geometry.get("budget") or infer_budget(samples, alpha_deg=alpha)
        geo.update(alpha_deg=alpha, pairs=geometry.get("pairs", PROTOCOL_PAIRS), budget=budget)
    first = read_rgb_exr(files[0])
    h, w = first.shape[:2]
    kw = dict(chunk=chunk, geometry=geo, attrs=dict(source=str(folder)), overwrite=overwrite)
    store = ChunkedStore.create(
        out_store, kind=kind, texel_shape=(h, w), item_shape=(len(files), 3), dtype=dtype, **kw
    )
    chunks_per_group = int(max(1, memory_limit // (store.chunk * len(files) * 3 * 4)))
    with progress_bar("exr import", store.n_texels, progress) as bar:
        for k0 in range(0, store.n_chunks, chunks_per_group):
            k1 = min(k0 + chunks_per_group, store.n_chunks)
            a, b = store.chunk_range(k0)[0], store.chunk_range(k1 - 1)[1]
            buf = np.empty((b - a, len(files), 3), np.float32)
            for j, f in enumerate(files):
                img = first if j == 0 else read_rgb_exr(f)
                if img.shape != (h, w, 3):
                    raise located(
                        f"image is {img.shape[1]}x{img.shape[0]}, the first one {w}x{h}", f
                    )
                buf[:, j] = img.reshape(-1, 3)[a:b]
            for k in range(k0, k1):
                c0, c1 = store.chunk_range(k)
                store.write_chunk(k, buf[c0 - a : c1 - a])
                bar.update(c1 - c0)
    return store
