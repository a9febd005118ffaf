"""``abrdf-jax btf``: generate, reconstruct, import, export and evaluate whole BTFs.

- ``abrdf-jax btf generate -o DIR --size N [--seed S]``: a procedural BTF (measurement store,
  dense reference store, parameter maps; see :mod:`abrdf_jax.btf._dataset`).
- ``abrdf-jax btf reconstruct MEAS -o OUT [--chunk N] [--exr-dir DIR]``: measurement store (or a
  generated BTF folder) → chunked ABRDF store, streamed, resumable (rerun the same command after
  an interruption), sharded over all local devices; ``--exr-dir`` also exports one EXR per pair.
- ``abrdf-jax btf import EXR_DIR -o STORE``: a folder of per-pair EXR images → chunked store.
- ``abrdf-jax btf export STORE --exr-dir DIR``: chunked store → one EXR image per pair.
- ``abrdf-jax btf evaluate REC REF [--png MAP.png]``: per-texel ΔE76 / LogErr against a reference.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from .._errors import InputError
from .._names import BTF_BACKENDS, BTF_MODELS, PRESETS, STORE_DTYPES
from . import _common as common

#: The configuration without ``--preset``/``--params``: linear in the log of the samples, so the
#: whole reconstruction is one matrix (``abrdf_jax.btf.reconstruct_btf``'s operator backend).
DEFAULT_PRESET = "operator"


def _init_distributed(args) -> None:
    given = [args.coordinator, args.num_processes, args.process_id]
    if any(x is not None for x in given) or args.distributed:
        from abrdf_jax.btf import init_distributed

        pid, n = init_distributed(args.coordinator, args.num_processes, args.process_id)
        print(f"jax.distributed: process {pid} of {n}", file=sys.stderr)


def cmd_generate(args) -> int:
    from abrdf_jax import btf

    t0 = time.perf_counter()
    paths = btf.generate_btf(args.output, args.size, args.seed, chunk=args.chunk,
                             reference=not args.no_reference, reference_dtype=args.reference_dtype,
                             progress=not args.quiet, overwrite=args.overwrite)
    n = args.size * args.size
    what = "measurements" + ("" if args.no_reference else " and dense reference")
    print(f"{args.output}: {args.size}x{args.size} texels ({n}), seed {args.seed}: {what} "
          f"in {time.perf_counter() - t0:.1f} s")
    if args.exr_dir:
        count = btf.write_exr_pairs(paths["measurements"], args.exr_dir, progress=not args.quiet)
        print(f"{args.exr_dir}: {count} measurement images (one per sample direction pair)")
    return 0


def _config_params(args, store):
    """Configuration and float32 parameters: a parameter file or ``abrdf_jax.preset`` (default operator)."""
    import jax.numpy as jnp

    geometry = store.geometry
    budget = "iso102" if args.isotropic else geometry.get("budget", "aniso204")
    alpha = float(geometry.get("alpha_deg", 15.0))
    config, params = common.params_for(budget, alpha, args.preset or DEFAULT_PRESET, args.params)
    return config, params.astype(jnp.float32)


def cmd_reconstruct(args) -> int:
    common.check_preset_or_params(args)
    _init_distributed(args)
    from abrdf_jax import btf

    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: not found")
    if src.is_dir() and any(btf.parse_pair_filename(p.name) for p in src.iterdir()):
        raise InputError(f"{src}: a folder of per-pair EXR images; import it first: "
                         f"abrdf-jax btf import {src} -o STORE")
    meas = btf.ChunkedStore.open(btf.measurement_store_of(src))
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    import jax

    if args.exr_dir and jax.process_count() > 1:
        raise InputError("--exr-dir with several processes: export once all have finished, "
                         "with 'abrdf-jax btf export'")
    config, params = _config_params(args, meas)
    stats: dict = {}
    store = btf.reconstruct_btf(meas, out, config, params, chunk=args.chunk, progress=not args.quiet,
                                dtype=args.dtype, devices=args.devices, backend=args.backend,
                                overwrite=args.overwrite, stats=stats, model=args.model)
    head = (f"{out}: {store.n_texels} texels ({stats['chunks_done']} chunks computed, {stats['chunks_skipped']} "
            f"already done) in {stats['seconds']:.1f} s")
    if stats["chunks_done"]:
        computed = store.n_texels * stats["chunks_done"] / store.n_chunks
        head += (f" (about {computed / max(stats['seconds'], 1e-9):.0f} texels/s; {stats['backend']} backend, "
                 f"{stats['devices']} device(s), {args.dtype})")
    print(head)
    if args.model == "auto":
        m = btf.isotropy_map(meas, chunk=args.chunk)
        print(f"model per texel (isotropy test of the axial slices): {100 * m['fraction_isotropic']:.1f}% "
              f"isotropic (diagonal-only model), {100 * (1 - m['fraction_isotropic']):.1f}% anisotropic")
    if args.exr_dir:
        if jax.process_index() == 0:
            t0 = time.perf_counter()
            count = btf.write_exr_pairs(store, args.exr_dir, progress=not args.quiet)
            print(f"{args.exr_dir}: {count} EXR images in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_import(args) -> int:
    from abrdf_jax import btf

    store = btf.read_exr_pairs(args.input, args.output, chunk=args.chunk, alpha_deg=args.alpha,
                               overwrite=args.overwrite, progress=not args.quiet)
    print(f"{args.output}: {store.kind} store, {store.texel_shape[0]}x{store.texel_shape[1]} texels, "
          f"{store.item_shape[0]} pairs per texel")
    return 0


def cmd_export(args) -> int:
    from abrdf_jax import btf

    count = btf.write_exr_pairs(args.input, args.exr_dir, half=not args.float32,
                                compression="none" if args.no_compression else "zip",
                                progress=not args.quiet)
    print(f"{args.exr_dir}: {count} EXR images")
    return 0


def cmd_evaluate(args) -> int:
    import numpy as np

    from abrdf_jax import btf

    rec, ref = btf.ChunkedStore.open(args.rec), btf.ChunkedStore.open(args.ref)
    for s in (rec, ref):
        if s.kind != "abrdf":
            raise InputError(f"{s.path}: is a {s.kind} store, expected a reconstruction or reference")
    maps = btf.texel_metrics(rec, ref, metrics=("de76", "logerr"))
    summary = {k: dict(mean=float(np.mean(v)), median=float(np.median(v)), p95=float(np.percentile(v, 95)),
                       max=float(np.max(v))) for k, v in maps.items()}
    if args.png:
        png = Path(args.png)
        if png.suffix.lower() != ".png" or not png.parent.is_dir():
            raise InputError(f"{png}: expected a .png file in an existing folder")
        btf.save_error_map(maps["de76"], png, title="ΔE76 per texel")
    if args.json:
        print(json.dumps(dict(rec=str(args.rec), ref=str(args.ref), **summary), indent=2))
    else:
        for k, v in summary.items():
            print(f"{k:<7} mean {v['mean']:.4g}  median {v['median']:.4g}  p95 {v['p95']:.4g}  max {v['max']:.4g}")
    return 0


def register(sub) -> None:
    """Add the ``btf`` subcommand (and its own subcommands) to the ``abrdf-jax`` parser."""
    b = sub.add_parser("btf", parents=[common.verbose_parent()],
                       help="whole BTFs: generate, reconstruct, import/export EXR, evaluate",
                       description="Spatially varying data: one ABRDF per texel, streamed through "
                       "chunked stores (see docs/btf.md).")
    bsub = b.add_subparsers(dest="btf_command", metavar="BTF_COMMAND")
    bsub.required = True

    verbose = common.verbose_parent()

    def shared(p):
        p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")

    g = bsub.add_parser("generate", parents=[verbose],
                        help="a procedural BTF with dense ground truth and slice measurements",
                        description="Generate a procedural BTF (height field, per-texel materials, "
                        "shadowing and masking) into DIR: measurements/ (204 slice samples per texel), "
                        "reference/ (81x81 per texel) and maps.npz.")
    g.add_argument("-o", "--output", required=True, metavar="DIR")
    g.add_argument("--size", required=True, type=common.positive("--size"), metavar="N", help="texels per side")
    g.add_argument("--seed", type=int, default=0, metavar="S")
    g.add_argument("--chunk", type=common.positive("--chunk"), default=1024, metavar="N", help="texels per chunk")
    g.add_argument("--no-reference", action="store_true", help="skip the dense ground truth")
    g.add_argument("--reference-dtype", choices=STORE_DTYPES, default=STORE_DTYPES[0])
    g.add_argument("--exr-dir", metavar="DIR", help="also write the measurements as one EXR per sample pair")
    g.add_argument("--overwrite", action="store_true", help="replace a different BTF in DIR")
    shared(g)
    g.set_defaults(func=cmd_generate)

    r = bsub.add_parser("reconstruct", parents=[verbose], help="measurement store -> chunked ABRDF store",
                        description="Reconstruct every texel's 81x81 ABRDF. Resumable: rerun the same "
                        "command after an interruption and finished chunks are kept.")
    r.add_argument("input", metavar="MEAS_DIR", help="a measurement store or a generated BTF folder")
    r.add_argument("-o", "--output", required=True, metavar="OUT", help="output store folder")
    r.add_argument("--chunk", type=common.positive("--chunk"), default=1024, metavar="N", help="texels per chunk")
    r.add_argument("--exr-dir", metavar="DIR", help="also export one EXR image per direction pair")
    r.add_argument("--dtype", choices=STORE_DTYPES, default=STORE_DTYPES[0], help="output values")
    r.add_argument("--preset", choices=PRESETS, default=None,
                   help="a " + common.preset_help(DEFAULT_PRESET)
                   + " (one matrix product per chunk; recommended and paper run the pipeline)")
    r.add_argument("--params", metavar="PARAMS.json", type=Path,
                   help="fitted configuration and parameters ('abrdf-jax fit'; instead of --preset)")
    r.add_argument("--isotropic", action="store_true", help="use only the diagonal slices (iso102)")
    r.add_argument("--backend", choices=BTF_BACKENDS, default=BTF_BACKENDS[0])
    r.add_argument("--model", choices=BTF_MODELS, default=BTF_MODELS[0],
                   help="auto: per texel, the isotropy test picks the diagonal-only or the anisotropic model "
                        "(two matrix products per chunk); fixed: one model for every texel (default)")
    r.add_argument("--devices", type=common.positive("--devices"), metavar="N", help="shard over the first N local devices")
    r.add_argument("--overwrite", action="store_true", help="replace an output store of other settings")
    d = r.add_argument_group("several hosts (jax.distributed; the stores on a shared file system)")
    d.add_argument("--distributed", action="store_true", help="initialise jax.distributed from the environment")
    d.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0")
    d.add_argument("--num-processes", type=common.positive("--num-processes"), metavar="N")
    d.add_argument("--process-id", type=int, metavar="K")
    shared(r)
    r.set_defaults(func=cmd_reconstruct)

    i = bsub.add_parser("import", parents=[verbose], help="folder of per-pair EXR images -> chunked store")
    i.add_argument("input", metavar="EXR_DIR")
    i.add_argument("-o", "--output", required=True, metavar="STORE")
    i.add_argument("--chunk", type=common.positive("--chunk"), default=1024, metavar="N")
    i.add_argument("--alpha", type=float, metavar="DEG", help="slice offset (default: pairs.json or estimated)")
    i.add_argument("--overwrite", action="store_true")
    shared(i)
    i.set_defaults(func=cmd_import)

    e = bsub.add_parser("export", parents=[verbose], help="chunked store -> one EXR image per direction pair")
    e.add_argument("input", metavar="STORE")
    e.add_argument("--exr-dir", required=True, metavar="DIR")
    e.add_argument("--float32", action="store_true", help="32-bit channels (default 16-bit half)")
    e.add_argument("--no-compression", action="store_true", help="uncompressed (faster, larger)")
    shared(e)
    e.set_defaults(func=cmd_export)

    v = bsub.add_parser("evaluate", parents=[verbose], help="per-texel accuracy against a dense reference store")
    v.add_argument("rec", metavar="REC")
    v.add_argument("ref", metavar="REF")
    v.add_argument("--png", metavar="MAP.png", help="save the ΔE76 map")
    v.add_argument("--json", action="store_true")
    shared(v)
    v.set_defaults(func=cmd_evaluate)
