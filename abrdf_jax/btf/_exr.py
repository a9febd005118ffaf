"""BTFs as one image per direction pair, the layout of the UBO2003 and UTIA databases.

A BTF database stores one rectified image of the sample per (illumination, view) pair, named by
the four angles in degrees (Bonn's convention, which UTIA follows):

``tl{θi}_pl{φi}_tv{θv}_pv{φv}.exr``  (e.g. ``tl075_pl015_tv030_pv120.exr``)

:func:`write_exr_pairs` writes one RGB OpenEXR image per pair, each angle as three digits when it
is whole (``030``) and with three decimals otherwise (``014.400``; slice samples lie between grid
azimuths); values linear RGB (``BRDF · cos θi``), half or float, ZIP compressed, and a
``pairs.json`` beside them with the exact angles and the file of each pair. Image row ``r``,
column ``c`` is texel ``r * width + c``. A reconstructed BTF is the 81 × 81 = 6561 UBO2003 pairs;
a measured one is its slice samples.

:func:`read_image_pairs` reads such images back, and those of a device or a database: PNG, JPEG
or EXR (:mod:`abrdf_jax.btf._images`), from a folder (any sub-folder) or a zip archive (the
UBO2003 downloads name their JPEGs ``tl075 pl015 tv030 pv120.jpg``, spaces between the angles),
with the angles in the capture's azimuth convention (:func:`capture_angles`). It prefers
``pairs.json`` to the rounded names and falls back to the names without it.

Both directions stream in bounded memory: writing gathers groups of pairs from the chunked
store, reading gathers groups of texel rows from the images (each image is decoded once per
group), with the group sizes set by ``memory_limit``.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import warnings
from pathlib import Path, PurePosixPath

import numpy as np

from .._errors import InputError, located
from .._grid import pair_grid
from .._names import AZIMUTHS
from ..io import atomic_write
from ..io._exr import write_rgb_exr
from ._images import DECODERS, ENCODINGS, open_source
from ._store import (
    ABRDF_GEOMETRY,
    ANGLES,
    CHUNKS,
    MANIFEST,
    ChunkedStore,
    make_folder,
    progress_bar,
)
from ._backend import open_store

PAIRS_INDEX = "pairs.json"
_ANGLE = r"(\d+(?:\.\d+)?)"
# tl075_pl015_tv030_pv120.png (UTIA, this package) or "tl075 pl015 tv030 pv120.jpg" (UBO2003)
_NAME = re.compile(rf"^tl{_ANGLE}[_ ]pl{_ANGLE}[_ ]tv{_ANGLE}[_ ]pv{_ANGLE}\.(\w+)$", re.I)


def _fmt(angle: float) -> str:
    a = float(angle) % 360.0 if float(angle) >= 360.0 else float(angle)
    if abs(a - round(a)) < 1e-9:
        return f"{int(round(a)):03d}"
    return f"{a:07.3f}"


def pair_filename(
    theta_i: float, phi_i: float, theta_v: float, phi_v: float, suffix: str = ".exr"
) -> str:
    """The image name of a direction pair (degrees), e.g. ``tl075_pl015_tv030_pv120.exr``."""
    return f"tl{_fmt(theta_i)}_pl{_fmt(phi_i)}_tv{_fmt(theta_v)}_pv{_fmt(phi_v)}{suffix}"


def parse_pair_filename(name: str) -> tuple[float, float, float, float] | None:
    """``(θi, φi, θv, φv)`` in degrees from an image name (``.png``, ``.jpg``, ``.jpeg`` or
    ``.exr``, any case; ``_`` or a space between the angles), or ``None`` if it does not match.
    The angles are as written: :func:`capture_angles` applies a capture's convention."""
    m = _NAME.match(Path(name).name)
    if m is None or "." + m.group(5).lower() not in DECODERS:
        return None
    return tuple(float(g) for g in m.groups()[:4])


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


def _check_convention(azimuth: str, light_offset_deg) -> float:
    if azimuth not in AZIMUTHS:
        raise InputError(f"azimuth must be one of {AZIMUTHS}, got {azimuth!r}")
    try:
        offset = float(light_offset_deg)
    except (TypeError, ValueError):
        offset = math.nan
    if not math.isfinite(offset):
        raise InputError(
            f"light_offset_deg must be a finite angle in degrees, got {light_offset_deg!r}"
        )
    return offset


def capture_angles(angles, azimuth: str = "ccw", light_offset_deg: float = 0.0) -> np.ndarray:
    """A capture's angles ``(P, 4)`` (θi, φi, θv, φv in degrees) in PROTOCOL.md's convention.

    ``azimuth="cw"``: both azimuths were measured clockwise, so they are mirrored,
    ``φ → (360 − φ) mod 360``; then ``light_offset_deg`` is added to every light azimuth (mod
    360). An azimuth at elevation 0 (the normal, whose direction it does not change) becomes 0,
    as on the UBO grid.

    Raises:
        InputError: an unknown ``azimuth`` or a light offset that is not a finite number.
    """
    offset = _check_convention(azimuth, light_offset_deg)
    a = np.array(angles, dtype=float).reshape(-1, 4)
    if azimuth == "cw":
        a[:, [1, 3]] = 360.0 - a[:, [1, 3]]
    a[:, 1] += offset
    a[:, [1, 3]] = np.mod(a[:, [1, 3]], 360.0)
    a[:, [1, 3]] = np.where(
        np.isclose(a[:, [1, 3]], 360.0) | (a[:, [0, 2]] < 1e-9), 0.0, a[:, [1, 3]]
    )
    return a


def _read_index(src, index: str) -> tuple[list[str], np.ndarray, dict]:
    base = PurePosixPath(index).parent
    try:
        doc = json.loads(src.read(index).decode("utf-8"))
        files = [(base / e["file"]).as_posix() for e in doc["pairs"]]
        angles = np.array([[e[k] for k in ANGLES] for e in doc["pairs"]], float)
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise located(f"cannot read the pair index: {e}", src.label(index)) from e
    have = set(src.names())
    for f in files:
        if f not in have:
            raise InputError(f"{src.label(f)}: listed in {PAIRS_INDEX} but missing")
        if PurePosixPath(f).suffix.lower() not in DECODERS:
            raise InputError(f"{src.label(f)}: listed in {PAIRS_INDEX}, not an image format read")
    return files, angles.reshape(-1, 4), dict(doc.get("geometry") or {})


def _list_pairs(src) -> tuple[list[str], np.ndarray, dict, str]:
    """Image files, their angles ``(P, 4)``, extra geometry and where the angles come from: the
    shallowest ``pairs.json`` if there is one, else the file names (any sub-folder)."""
    names = src.names()
    index = sorted((n.count("/"), n) for n in names if PurePosixPath(n).name == PAIRS_INDEX)
    if index:
        return (*_read_index(src, index[0][1]), PAIRS_INDEX)
    found, other = [], []
    for n in names:
        m = _NAME.match(PurePosixPath(n.replace("\\", "/")).name)  # zips made on Windows
        if m is not None:
            (found if "." + m.group(5).lower() in DECODERS else other).append((n, m))
    if other:
        warnings.warn(
            f"{src.path}: {len(other)} file(s) named like direction pairs but in a format not "
            f"read were left out (first: {other[0][0]}); read are {', '.join(DECODERS)}",
            stacklevel=3,
        )
    if not found:
        raise InputError(
            f"{src.path}: no images named like tl030_pl000_tv030_pv000.png ({', '.join(DECODERS)}; "
            f"'_' or ' ' between the angles) and no {PAIRS_INDEX}"
        )
    angles = np.array([[float(g) for g in m.groups()[:4]] for _, m in found])
    return [n for n, _ in found], angles, {}, "file names"


def _check_pairs(src, files: list[str], angles: np.ndarray) -> None:
    """Refuse two images of one direction pair, and sRGB images mixed with linear EXR ones."""
    key = np.round(angles, 3)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        j = first[np.argmax(counts > 1)]
        k = next(i for i in range(len(files)) if i != j and (key[i] == key[j]).all())
        pair = ", ".join(f"{x:g}" for x in angles[j])
        raise InputError(
            f"{src.label(files[j])} and {src.label(files[k])}: two images of the direction pair "
            f"(θi, φi, θv, φv) = ({pair}) in the package's convention"
        )
    by = {}
    for f in files:
        by.setdefault(ENCODINGS[PurePosixPath(f).suffix.lower()], f)
    if len(by) > 1:
        raise InputError(
            f"{src.path}: mixes linear EXR images ({src.label(by['linear'])}) with sRGB PNG/JPEG "
            f"images ({src.label(by['sRGB'])}); their values are on different scales: convert "
            "them to one format"
        )


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


def _geometry(angles: np.ndarray, index_geometry: dict, alpha_deg) -> tuple[str, dict]:
    """The store kind and geometry of a capture's pairs (see :func:`read_image_pairs`)."""
    from .._grouping import estimate_alpha, infer_pairs
    from .._measurements import Samples
    from .._pipeline import infer_budget

    samples = Samples(*angles.T, np.zeros((len(angles), 3)))
    alpha = index_geometry.get("alpha_deg") if alpha_deg is None else alpha_deg
    alpha = float(round(float(estimate_alpha(samples)), 3) if alpha is None else alpha)
    geo = {k: angles[:, j].tolist() for j, k in enumerate(ANGLES)}
    budget = index_geometry.get("budget") or infer_budget(samples, alpha_deg=alpha)
    # the capture's own elevation pairs (a device's, extra ones) unless pairs.json names them
    pairs = index_geometry.get("pairs") or [
        list(p) for p in infer_pairs(angles[:, 0], angles[:, 2])[0]
    ]
    geo.update(alpha_deg=alpha, pairs=pairs, budget=budget)
    return "measurements", geo


def _gather(src, files, a: int, b: int, shape, bar, first=None) -> tuple[np.ndarray, set]:
    """Texels ``[a, b)`` of every image ``(b − a, P, 3)``, each image decoded once, and what
    the images were (8-bit sRGB, linear EXR, ...)."""
    h, w = shape
    buf, kinds = np.empty((b - a, len(files), 3), np.float32), set()
    for j, f in enumerate(files):
        img, what = first if (j == 0 and first is not None) else src.image(f)
        bar.update(1)
        if img.shape != (h, w, 3):
            got = f"{img.shape[1]}x{img.shape[0]}"
            raise InputError(
                f"{src.label(f)}: image is {got} (width x height), the first one "
                f"({src.label(files[0])}) {w}x{h}"
            )
        buf[:, j] = img.reshape(-1, 3)[a:b]
        kinds.add(what)
    return buf, kinds


def _new_store(out, src, kinds, angles, ubo, shape, extra, opts) -> ChunkedStore:
    """The store of a capture whose images were all read once (warns if they mix bit depths)."""
    if len(kinds) > 1:
        warnings.warn(
            f"{src.path}: images of {' and '.join(sorted(kinds))}; each is decoded to linear "
            "[0, 1] by its own bit depth",
            stacklevel=3,
        )
    if ubo is None:
        kind, geo = _geometry(angles, extra["index_geometry"], extra["alpha_deg"])
    else:
        kind, geo = "abrdf", ABRDF_GEOMETRY
    attrs = dict(source=str(src.path), images=sorted(kinds), angles=extra["convention"])
    return ChunkedStore.create(
        out,
        kind=kind,
        texel_shape=shape,
        item_shape=(len(angles), 3),
        geometry=geo,
        attrs=attrs,
        **opts,
    )


def _remove_store(path: Path, made_folder: bool) -> None:
    """Undo a failed import: the store's chunks and manifest (and the folder if it was made)."""
    with contextlib.suppress(OSError, InputError):
        ChunkedStore.open(path).remove_chunks()
    for p in (path / MANIFEST, path / CHUNKS):
        with contextlib.suppress(OSError):
            p.rmdir() if p.is_dir() else p.unlink()
    if made_folder:
        with contextlib.suppress(OSError):
            path.rmdir()


def read_image_pairs(
    source,
    out_store,
    *,
    chunk: int = 1024,
    dtype: str = "float32",
    alpha_deg: float | None = None,
    azimuth: str = "ccw",
    light_offset_deg: float = 0.0,
    memory_limit: int = 1 << 30,
    overwrite: bool = False,
    progress: bool = False,
) -> ChunkedStore:
    """Read one image per direction pair, from a folder or a zip archive, into a chunked store.

    The images are PNG, JPEG (sRGB, decoded to linear) or OpenEXR (linear, as is), named in the
    UBO/UTIA convention ``tl{θi}_pl{φi}_tv{θv}_pv{φv}.png`` (``_`` or a space between the
    angles, as in the UBO2003 zips; any sub-folder) or listed in a ``pairs.json``
    (:mod:`abrdf_jax.btf._images`, ``docs/btf.md``). The exact 6561 UBO2003 pairs make an
    ``"abrdf"`` store (in ``table[i, v]`` order); any other set of pairs makes a
    ``"measurements"`` store whose geometry is the pairs' angles (α read from ``pairs.json``,
    given, or estimated from the angles), ready for :func:`abrdf_jax.btf.reconstruct_btf`.

    Args:
        source: the image folder or ``.zip`` archive.
        out_store: the store folder to create.
        chunk: texels per chunk.
        dtype: store dtype.
        alpha_deg: slice offset of a measurement (default: ``pairs.json`` or estimated).
        azimuth: ``"ccw"`` (default: PROTOCOL.md's counter-clockwise azimuths, what
            :func:`write_exr_pairs` writes) or ``"cw"`` (mirrored, :func:`capture_angles`).
        light_offset_deg: added to every light azimuth after that (e.g. 180 for a device whose
            light azimuth is counted from the opposite side).
        memory_limit: bytes of texel rows gathered at a time.
        overwrite: replace a different store at ``out_store``.
        progress: show a progress bar.

    Returns:
        The store; its ``attrs`` record the source, the image kinds and the angle convention.

    Raises:
        InputError: no images, two images of one pair, EXR mixed with PNG/JPEG, images of
            different sizes, unreadable or corrupt images, NaN or infinity in an EXR, a bad
            convention. Nothing is written then: every image is decoded whole for the first
            group of texels, before the store is created; a failure after that (a file changed
            during the import) removes the store again.
    """
    offset = _check_convention(azimuth, light_offset_deg)
    if not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise InputError(f"chunk must be a positive integer, got {chunk!r}")
    convention = dict(azimuth=azimuth, light_offset_deg=offset)
    convention.update(stored="PROTOCOL.md: counter-clockwise azimuths, x = sinθ cosφ")
    out = Path(out_store)
    made, store = not out.exists(), None
    with open_source(source) as src:
        files, angles, index_geometry, convention["read_from"] = _list_pairs(src)
        extra = dict(index_geometry=index_geometry, alpha_deg=alpha_deg, convention=convention)
        angles = capture_angles(angles, azimuth, offset)
        if convention["read_from"] != PAIRS_INDEX:  # in numeric order of (θi, φi, θv, φv)
            order = np.lexsort(angles.T[::-1])
            files, angles = [files[i] for i in order], angles[order]
        _check_pairs(src, files, angles)
        ubo = _match_ubo(angles)
        files = files if ubo is None else [files[i] for i in ubo]
        first = src.image(files[0])
        (h, w), n = first[0].shape[:2], first[0].shape[0] * first[0].shape[1]
        per_group = int(max(1, memory_limit // (chunk * len(files) * 3 * 4)))
        n_chunks = -(-n // chunk)
        groups = [(k, min(k + per_group, n_chunks)) for k in range(0, n_chunks, per_group)]
        # the bar counts images decoded: each once per group of texels
        with progress_bar("image import", len(groups) * len(files), progress, unit="image") as bar:
            try:
                for k0, k1 in groups:
                    a, b = k0 * chunk, min(k1 * chunk, n)
                    buf, kinds = _gather(src, files, a, b, (h, w), bar, first)
                    first = None
                    if store is None:  # every image was decoded whole once: all are readable
                        opts = dict(chunk=chunk, dtype=dtype, overwrite=overwrite)
                        store = _new_store(out, src, kinds, angles, ubo, (h, w), extra, opts)
                    for k in range(k0, k1):
                        c0, c1 = store.chunk_range(k)
                        store.write_chunk(k, buf[c0 - a : c1 - a])
            except BaseException:
                if store is not None:  # a file changed during the import, or a write failed
                    _remove_store(out, made)
                raise
    return store


#: The former name of :func:`read_image_pairs` (it read EXR folders only).
read_exr_pairs = read_image_pairs
