"""``abrdf-jax btf``: generate, reconstruct, import, export and evaluate whole BTFs.

- ``abrdf-jax btf generate -o DIR --size N [--seed S]``: a procedural BTF (measurement store,
  dense reference store, parameter maps; see :mod:`abrdf_jax.btf._dataset`).
- ``abrdf-jax btf reconstruct MEAS -o OUT [--chunk N] [--exr-dir DIR]``: measurement store (or a
  generated BTF folder) → chunked ABRDF store, streamed, resumable (rerun the same command after
  an interruption), sharded over all local devices; ``--exr-dir`` also exports one EXR per pair.
- ``abrdf-jax btf import IMAGES -o STORE [--azimuth cw] [--light-offset DEG]``: a folder or a zip
  archive of per-pair PNG/JPEG/EXR images (UBO2003/UTIA names) → chunked store.
- ``abrdf-jax btf export STORE --exr-dir DIR``: chunked store → one EXR image per pair;
  ``--zarr OUT.zarr``: an ``.npy`` store → a zarr v3 group.
- ``abrdf-jax btf evaluate REC REF [--png MAP.png]``: per-texel ΔE76 / LogErr against a reference.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from pathlib import Path

from .._errors import InputError
from .._names import (
    AZIMUTHS,
    BTF_BACKENDS,
    BTF_MODELS,
    DIRECT_MODELS,
    LEARNED_MODELS,
    PRESETS,
)
from .._names import STORE_DTYPES, STORE_FORMATS
from . import _common as common

#: The configuration without ``--preset``/``--params``: linear in the log of the samples, so the
#: whole reconstruction is one matrix (``abrdf_jax.btf.reconstruct_btf``'s operator backend).
DEFAULT_PRESET = "operator"
#: The ``--help`` texts: each command's and each option's (an option's own text, where it differs
#: between commands, is given in place).
HELP = {
    "btf": "whole BTFs: generate, reconstruct, import images, export EXR, evaluate",
    "generate": "a procedural BTF with dense ground truth and slice measurements",
    "reconstruct": "measurement store -> chunked ABRDF store",
    "import": "per-pair PNG/JPEG/EXR images (folder or .zip) -> chunked store",
    "export": "chunked store -> one EXR image per direction pair",
    "evaluate": "per-texel accuracy against a dense reference store",
    "--quiet": "no progress bar",
    "--size": "texels per side",
    "--chunk": "texels per chunk",
    "--no-reference": "skip the dense ground truth",
    "--dtype": "output values",
    "--preset": "a " + common.preset_help(DEFAULT_PRESET) + " (one matrix product per chunk; "
    "recommended and paper run the pipeline)",
    "--params": "fitted configuration and parameters ('abrdf-jax fit'; instead of --preset)",
    "--model": "auto: per texel, the isotropy test picks the bivariate (isotropic) or the "
    "anisotropic model (two matrix products per chunk); fixed: one model for every texel "
    "(default); prior / fused: every texel with a learned prior alone / fused with a kernel on "
    "its residual (docs/prior.md); bivariate: every texel with the bivariate (theta_h, theta_d) "
    "model of isotropic materials (one matrix product per chunk)",
    "--prior": "the prior of --model prior|fused: a prior file ('abrdf-jax prior train') or "
    "'default' (the built-in prior, also without the flag)",
    "--devices": "shard over the first N local devices",
    "hosts": "several hosts (jax.distributed; the stores on a shared file system)",
    "--distributed": "initialise jax.distributed from the environment",
    "--coordinator": "address of process 0",
    "--float32": "32-bit channels (default 16-bit half)",
    "--no-compression": "uncompressed (faster, larger)",
    "--png": "save the ΔE76 map",
    "--format": "output store: npy (default: a manifest and one checksummed .npy per chunk) or "
    "zarr (a zarr v3 group for xarray/dask/napari; pip install abrdf_jax[zarr])",
    "--azimuth": "how the image names count azimuths: ccw, counter-clockwise as PROTOCOL.md "
    "(default; what 'btf export' writes), or cw, clockwise (mirrored: phi -> 360 - phi)",
    "--light-offset": "degrees added to every light azimuth, after --azimuth (e.g. 180 when the "
    "device counts the light's azimuth from the opposite side; default 0)",
}
DESCRIPTION = {
    "btf": "Spatially varying data: one ABRDF per texel, streamed through chunked stores (see "
    "docs/btf.md).",
    "generate": "Generate a procedural BTF (height field, per-texel materials, shadowing and "
    "masking) into DIR: measurements/ (204 slice samples per texel), reference/ (81x81 per "
    "texel) and maps.npz.",
    "reconstruct": "Reconstruct every texel's 81x81 ABRDF. Resumable: rerun the same command "
    "after an interruption and finished chunks are kept.",
    "import": "Read one image per (light, view) direction pair into a chunked store: PNG or JPEG "
    "(8-bit, or 16-bit PNG; sRGB decoded to linear) or OpenEXR (linear, as is), named "
    "tl{theta_i}_pl{phi_i}_tv{theta_v}_pv{phi_v}.png as in the UBO2003 and UTIA BTF databases "
    "('_' or ' ' between the angles, any case, any sub-folder) or listed in a pairs.json; a "
    "folder or a .zip archive (the UBO2003 downloads), read without extracting. The 6561 UBO "
    "pairs make an ABRDF store, other pairs a measurement store for 'btf reconstruct'. Angles in "
    "another azimuth convention: --azimuth, --light-offset (docs/btf.md, 'Reading image "
    "captures'); the convention used is recorded in the store's manifest.",
}


def _init_distributed(args) -> None:
    given = [args.coordinator, args.num_processes, args.process_id]
    if any(x is not None for x in given) or args.distributed:
        from abrdf_jax.btf import init_distributed

        pid, n = init_distributed(args.coordinator, args.num_processes, args.process_id)
        print(f"jax.distributed: process {pid} of {n}", file=sys.stderr)


def _refusing(write, *args, **kw):
    """``write(*args, **kw)``, a store writer whose refusal of a store of other settings names
    ``--overwrite`` (the overwrite policy, :data:`abrdf_jax.cli._common.OVERWRITE_POLICY`)."""
    try:
        return write(*args, **kw)
    except InputError as e:
        raise common.refused_store(e) from e


def cmd_generate(args) -> int:
    from abrdf_jax import btf

    t0 = time.perf_counter()
    opts = dict(chunk=args.chunk, reference=not args.no_reference, overwrite=args.overwrite)
    opts |= dict(reference_dtype=args.reference_dtype, progress=not args.quiet)
    paths = _refusing(btf.generate_btf, args.output, args.size, args.seed, **opts)
    n = args.size * args.size
    what = "measurements" + ("" if args.no_reference else " and dense reference")
    print(
        f"{args.output}: {args.size}x{args.size} texels ({n}), seed {args.seed}: {what} in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    if args.exr_dir:
        count = btf.write_exr_pairs(paths["measurements"], args.exr_dir, progress=not args.quiet)
        print(f"{args.exr_dir}: {count} measurement images (one per sample direction pair)")
    return 0


def _config_params(args, store):
    """Configuration and float32 parameters: a parameter file or a preset (default operator)."""
    import jax.numpy as jnp

    geometry = store.geometry
    budget = "iso102" if args.isotropic else geometry.get("budget", "aniso204")
    alpha = float(geometry.get("alpha_deg", 15.0))
    config, params = common.params_for(budget, alpha, args.preset or DEFAULT_PRESET, args.params)
    return config, params.astype(jnp.float32)


def _is_image_capture(src: Path, btf) -> bool:
    """A zip or a folder of per-pair images (not a store or a generated BTF folder)."""
    if src.is_file():
        return src.suffix.lower() == ".zip"
    return not (src / "manifest.json").exists() and any(
        btf.parse_pair_filename(p.name) for p in src.iterdir()
    )


def _import_capture(src: Path, out: Path, args, btf):
    """Import an image capture into the store ``OUT.measurements`` beside the output (once: a
    rerun finds it), with PROTOCOL.md's azimuth convention (else ``abrdf-jax btf import``)."""
    store = out.parent / (out.name + ".measurements")
    if not out.parent.is_dir():
        raise InputError(f"{out}: parent folder {out.parent} does not exist")
    if store.exists():
        found = btf.ChunkedStore.open(store)
        if found.attrs.get("source") == str(src) and not found.verify():
            print(f"{store}: imported before from {src}; reused")
            return found
    print(
        f"{store}: importing the images of {src} (azimuth ccw, no light offset; other "
        "conventions: abrdf-jax btf import --azimuth/--light-offset)"
    )
    opts = dict(overwrite=True, progress=not args.quiet, chunk=args.chunk)
    return btf.read_image_pairs(src, store, **opts)


def keep_chunk_outputs(chunk: int, dtype: str, devices=None) -> bool:
    """Let the C allocator keep one chunk's output (``chunk`` texels, padded as the chunk map on
    ``devices`` pads them (``reconstruct_btf``'s argument: ``None`` all local devices, a count or
    a list), × 81 × 81 × RGB of ``dtype``) for the next chunk: ``btf reconstruct`` allocates it
    anew per chunk, above glibc's own mmap ceiling (:mod:`abrdf_jax.cli._malloc`). ``True`` when
    the thresholds were set.

    Raises:
        InputError: ``devices`` names more devices than there are (as ``reconstruct_btf``)."""
    import numpy as np

    from ..btf._chunkfn import N_PAIRS  # a chunk map's tables: (texels, N_PAIRS, 3)
    from ..btf._devices import padded_batch, resolve_devices

    texels = padded_batch(chunk, len(resolve_devices(devices)))
    return common.keep_freed_blocks(texels * N_PAIRS * 3 * np.dtype(dtype).itemsize)


def cmd_reconstruct(args) -> int:
    if args.preset is not None and args.params is not None:
        raise InputError(
            f"--preset {args.preset} and --params {args.params} both fix the "
            "configuration; give one"
        )
    common.check_params_file(args.params)  # before any work, without JAX
    learned = args.model in LEARNED_MODELS
    if args.prior is not None and not learned:
        raise InputError(f"--prior is read by --model prior|fused, not --model {args.model}")
    if args.model in (*LEARNED_MODELS, *DIRECT_MODELS) and (args.preset or args.params):
        flag = "--preset" if args.preset is not None else "--params"
        what = "reads a prior" if learned else "is not an RBF model"
        raise InputError(f"{flag} sets an RBF model; --model {args.model} {what}")
    source = None
    if learned and args.prior not in (None, "default"):
        from .._prior_operator import read_source

        source = read_source(args.prior)  # a bad file: named, before any work (no JAX)
    _init_distributed(args)
    from abrdf_jax import btf

    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: not found")
    out = common.check_output_folder(Path(args.output))
    if _is_image_capture(src, btf):
        meas = _import_capture(src, out, args, btf)
    else:
        meas = btf.ChunkedStore.open(btf.measurement_store_of(src))
    # a rerun (after an interruption, say) loads what this run compiles
    common.compilation_cache(args.cache_dir, common.warn)
    import jax

    if args.exr_dir and jax.process_count() > 1:
        how = "export once all have finished, with 'abrdf-jax btf export'"
        raise InputError(f"--exr-dir with several processes: {how}")
    config, params = _config_params(args, meas)
    keep_chunk_outputs(args.chunk, args.dtype, args.devices)
    stats: dict = {}
    opts = dict(chunk=args.chunk, progress=not args.quiet, dtype=args.dtype, devices=args.devices)
    opts |= dict(backend=args.backend, overwrite=args.overwrite, stats=stats, model=args.model)
    opts |= dict(format=args.format)
    if learned:
        from .._prior_operator import resolve_prior

        source = source or resolve_prior(args.prior, args.cache_dir)
        opts |= dict(prior=source.load())
    # one writer of the store (several hosts of one jax.distributed job share it on purpose)
    with common.output_lock(out) if jax.process_count() == 1 else contextlib.nullcontext():
        try:
            store = _refusing(btf.reconstruct_btf, meas, out, config, params, **opts)
        except InputError as e:
            if not learned or "chunk" not in str(e):
                raise
            raise InputError(
                f"{e} (--model {args.model} extrapolates its database's lobes onto texels "
                "unlike it: docs/btf.md, 'Learned models per texel'; --model fixed is the RBF)"
            ) from e
    done, seconds = stats["chunks_done"], stats["seconds"]
    head = (
        f"{out}: {store.n_texels} texels ({done} chunks computed, {stats['chunks_skipped']} "
        f"already done) in {seconds:.1f} s"
    )
    if done:
        rate = store.n_texels * done / store.n_chunks / max(seconds, 1e-9)
        head += (
            f" (about {rate:.0f} texels/s; {stats['backend']} backend, {stats['devices']} "
            f"device(s), {args.dtype})"
        )
    print(head)
    if args.model == "auto":
        iso = btf.isotropy_map(meas, chunk=args.chunk)["fraction_isotropic"]
        print(
            f"model per texel (isotropy test of the axial slices): {100 * iso:.1f}% isotropic "
            f"(bivariate model), {100 * (1 - iso):.1f}% anisotropic"
        )
    if args.exr_dir and jax.process_index() == 0:
        t0 = time.perf_counter()
        count = btf.write_exr_pairs(store, args.exr_dir, progress=not args.quiet)
        print(f"{args.exr_dir}: {count} EXR images in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_import(args) -> int:
    import warnings

    from abrdf_jax import btf

    opts = dict(alpha_deg=args.alpha, overwrite=args.overwrite, progress=not args.quiet)
    opts |= dict(azimuth=args.azimuth, light_offset_deg=args.light_offset)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            store = _refusing(
                btf.read_image_pairs, args.input, args.output, chunk=args.chunk, **opts
            )
        finally:
            for message in caught:
                common.warn(str(message.message))
    (h, w), pairs = store.texel_shape[:2], store.item_shape[0]
    how = f"azimuths {args.azimuth}"
    how += f", light {args.light_offset:+g}°" if args.light_offset else ""
    images = " and ".join(store.attrs.get("images", []))
    print(
        f"{args.output}: {store.kind} store, {h}x{w} texels, {pairs} pairs per texel "
        f"({images}; {how})"
    )
    if store.kind == "measurements":  # 360° − α or α + 180° hint at another convention
        g = store.geometry
        print(f"{args.output}: slice offset alpha {g['alpha_deg']:g}°, budget {g['budget']}")
    return 0


def cmd_export(args) -> int:
    if (args.exr_dir is None) == (args.zarr is None):
        raise InputError("btf export: give one of --exr-dir DIR or --zarr OUT.zarr")
    common.check_output_folder(Path(args.zarr or args.exr_dir))
    from abrdf_jax import btf

    if args.zarr:
        opts = dict(progress=not args.quiet, overwrite=args.overwrite)
        store = _refusing(btf.export_zarr, args.input, args.zarr, **opts)
        print(f"{args.zarr}: zarr v3 group, {store.n_chunks} chunks of {store.chunk} texels")
        return 0

    compression = "none" if args.no_compression else "zip"
    opts = dict(half=not args.float32, compression=compression, progress=not args.quiet)
    count = btf.write_exr_pairs(args.input, args.exr_dir, **opts)
    print(f"{args.exr_dir}: {count} EXR images")
    return 0


def cmd_evaluate(args) -> int:
    import numpy as np

    if args.png:  # before any work
        png = Path(args.png)
        if png.suffix.lower() != ".png":
            raise InputError(f"{png}: expected a .png file in an existing folder")
        common.check_output_file(png, (".png",), "map")
    from abrdf_jax import btf

    rec, ref = btf.open_store(args.rec), btf.open_store(args.ref)
    for s in (rec, ref):
        if s.kind != "abrdf":
            what = "expected a reconstruction or reference"
            raise InputError(f"{s.path}: is a {s.kind} store, {what}")
    maps = btf.texel_metrics(rec, ref, metrics=("de76", "logerr"))
    stats = {"mean": np.mean, "median": np.median, "p95": lambda v: np.percentile(v, 95)}
    stats["max"] = np.max
    summary = {k: {s: float(f(v)) for s, f in stats.items()} for k, v in maps.items()}
    if args.png:
        png = Path(args.png)
        common.announce_replace(png)
        btf.save_error_map(maps["de76"], png, title="ΔE76 per texel")
    if args.json:
        print(json.dumps(dict(rec=str(args.rec), ref=str(args.ref), **summary), indent=2))
    else:
        for k, v in summary.items():
            print(f"{k:<7}" + "".join(f" {s} {x:.4g} " for s, x in v.items()).rstrip())
    return 0


def register(sub) -> None:
    b = common.command(sub, "btf", None, HELP["btf"], DESCRIPTION["btf"])
    bsub = b.add_subparsers(dest="btf_command", metavar="BTF_COMMAND", required=True)
    chunk = dict(type=common.positive("--chunk"), default=1024, metavar="N")

    g = common.command(
        bsub, "generate", cmd_generate, HELP["generate"], DESCRIPTION["generate"], writes=True
    )
    add = common.adder(g, HELP)
    add("-o", "--output", required=True, type=common.output_path, metavar="DIR")
    add("--size", required=True, type=common.positive("--size"), metavar="N")
    add("--seed", type=common.integer("--seed", 0), default=0, metavar="S")
    add("--chunk", **chunk)
    add("--no-reference", action="store_true")
    add("--reference-dtype", choices=STORE_DTYPES, default=STORE_DTYPES[0])
    add(
        "--exr-dir",
        type=common.output_path,
        metavar="DIR",
        help="also write the measurements as one EXR per sample pair",
    )
    add("--overwrite", action="store_true", help="replace a different BTF in DIR")
    add("-q", "--quiet", action="store_true")

    r = common.command(
        bsub,
        "reconstruct",
        cmd_reconstruct,
        HELP["reconstruct"],
        DESCRIPTION["reconstruct"],
        writes=True,
    )
    add = common.adder(r, HELP)
    what = "a measurement store, a generated BTF folder, or an image capture (a folder or zip of "
    what += "per-pair images, imported first to OUT.measurements)"
    add("input", type=common.existing("file or folder"), metavar="MEAS_DIR", help=what)
    add(
        "-o",
        "--output",
        required=True,
        type=common.output_path,
        metavar="OUT",
        help="output store folder",
    )
    add("--chunk", **chunk)
    add(
        "--exr-dir",
        type=common.output_path,
        metavar="DIR",
        help="also export one EXR image per direction pair",
    )
    add("--dtype", choices=STORE_DTYPES, default=STORE_DTYPES[0])
    add("--preset", choices=PRESETS)
    add("--params", metavar="PARAMS.json", type=common.existing("file"))
    common.budget_flags(r, anisotropic=False)
    add("--backend", choices=BTF_BACKENDS, default=BTF_BACKENDS[0])
    add("--model", choices=BTF_MODELS, default=BTF_MODELS[0])
    add("--prior", metavar="FILE")
    add("--format", choices=STORE_FORMATS, default=STORE_FORMATS[0])
    add("--devices", type=common.positive("--devices"), metavar="N")
    add("--overwrite", action="store_true", help="replace an output store of other settings")
    add("--cache-dir", metavar="DIR", help=common.CACHE_DIR_HELP)
    d = common.adder(r.add_argument_group(HELP["hosts"]), HELP)
    d("--distributed", action="store_true")
    d("--coordinator", metavar="HOST:PORT")
    d("--num-processes", type=common.positive("--num-processes"), metavar="N")
    d("--process-id", type=common.integer("--process-id", 0), metavar="K")
    add("-q", "--quiet", action="store_true")

    i = common.command(
        bsub, "import", cmd_import, HELP["import"], DESCRIPTION["import"], writes=True
    )
    add = common.adder(i, HELP)
    images = "a folder (any sub-folder) or a .zip archive of images"
    add("input", type=common.existing("file or folder"), metavar="IMAGES", help=images)
    add("-o", "--output", required=True, type=common.output_path, metavar="STORE")
    add("--chunk", **chunk)
    add(
        "--alpha",
        type=common.alpha_deg,
        metavar="DEG",
        help="slice offset (default: pairs.json or estimated)",
    )
    add("--azimuth", choices=AZIMUTHS, default=AZIMUTHS[0])
    add("--light-offset", type=common.degrees("--light-offset"), default=0.0, metavar="DEG")
    add("--overwrite", action="store_true", help="replace a different store at STORE")
    add("-q", "--quiet", action="store_true")

    e = common.command(bsub, "export", cmd_export, HELP["export"], writes=True)
    add = common.adder(e, HELP)
    add("input", type=common.existing("folder"), metavar="STORE")
    add("--exr-dir", type=common.output_path, metavar="DIR")
    add(
        "--zarr",
        type=common.output_path,
        metavar="OUT.zarr",
        help="an .npy ABRDF store -> a zarr v3 group",
    )
    add("--overwrite", action="store_true", help="replace an existing OUT.zarr")
    add("--float32", action="store_true")
    add("--no-compression", action="store_true")
    add("-q", "--quiet", action="store_true")

    v = common.command(bsub, "evaluate", cmd_evaluate, HELP["evaluate"], writes=True)
    add = common.adder(v, HELP)
    add("rec", type=common.existing("folder"), metavar="REC")
    add("ref", type=common.existing("folder"), metavar="REF")
    add("--png", metavar="MAP.png")
    add("--json", action="store_true")
    add("-q", "--quiet", action="store_true")
