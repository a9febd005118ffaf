"""The ``abrdf-jax`` command line: reconstruct, sample, evaluate, demo, materials.

Bad input (a missing or malformed file, an unknown name, an unwritable output) ends with one
line ``abrdf-jax: error: ...`` on stderr and exit status 2, never a traceback (``-v`` shows it).
Every output file is written atomically: a failed run leaves no partial file and does not touch
an existing one. Heavy imports (JAX) happen inside the subcommands, so ``--help`` is quick.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import traceback
from pathlib import Path

from .._errors import InputError

PROG = "abrdf-jax"
TABLE_EXTENSIONS = (".npz", ".exr")
BUDGETS = ("iso102", "aniso204")
_CHUNK = 32  # materials per batched reconstruction call (bounds memory, drives the progress bar)


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("abrdf_jax")
    except Exception:  # noqa: BLE001 - not installed: fall back to the source tree's version
        from .. import __version__

        return __version__


def _check_output_file(path: Path, extensions: tuple[str, ...], what: str) -> Path:
    """Fail before any work when ``path`` cannot be an output of the given kind."""
    if path.suffix.lower() not in extensions:
        raise InputError(
            f"{path}: unknown {what} extension {path.suffix or '(none)'!r}; use {' or '.join(extensions)}"
        )
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"{path}: output folder {parent} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{path}: output folder {parent} is not writable")
    return path


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def _metrics_floats(d) -> dict[str, float]:
    return {k: float(v) for k, v in d.items()}


def _expand_inputs(inputs: list[str]) -> tuple[list[Path], bool]:
    """Measurement files named on the command line; a folder contributes its ``*.csv`` files.

    Returns the files and whether the output is a folder (several inputs or a folder input).
    """
    files: list[Path] = []
    folder_mode = len(inputs) > 1
    for name in inputs:
        p = Path(name)
        if p.is_dir():
            folder_mode = True
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() == ".csv")
            if not found:
                raise InputError(f"{p}: folder holds no .csv measurement files")
            files.extend(found)
        else:
            if not p.exists():
                raise InputError(f"{p}: file not found")
            files.append(p)
    return files, folder_mode


def _params_for(aj, budget: str, alpha_deg: float, preset: str = "recommended", params_file=None):
    """Config and params: from a fitted parameter file (``--params``) or a preset's defaults.

    A parameter file supplies the configuration, widths and λ; α stays the measurement's own
    (it says where the samples lie), and the file's budget must match the data's.
    """
    if params_file is not None:
        from abrdf_jax.tuning import load_params

        config, params, _ = load_params(params_file)
        if config.budget != budget:
            raise InputError(
                f"{params_file}: parameters were fitted for {config.budget}, but the measurement is {budget}; "
                f"fit for {budget} or pass --{'isotropic' if config.budget == 'iso102' else 'anisotropic'}"
            )
        import jax.numpy as jnp

        alpha = jnp.asarray(aj.Params.default(config, alpha_deg=alpha_deg).alpha, params.alpha.dtype)
        return config, aj.Params(alpha, params.widths, params.reg)
    config = aj.Config.recommended(budget) if preset == "recommended" else aj.Config(budget=budget)
    return config, aj.Params.default(config, alpha_deg=alpha_deg)


def _plan(aj, samples, forced_budget: str | None, alpha: float | None, where: Path) -> tuple[str, float]:
    """The budget and slice offset α of one measurement (forced or read off the data)."""
    a = float(alpha) if alpha is not None else round(float(aj.estimate_alpha(samples)), 3)
    try:
        found = aj.infer_budget(samples, alpha_deg=a)
    except InputError as e:
        raise InputError(f"{where}: {e} (slice offset alpha {a:g} deg)") from e
    if forced_budget == "aniso204" and found != "aniso204":
        raise InputError(f"{where}: --anisotropic needs axial slices, but the file has none")
    return forced_budget or found, a


# --------------------------------------------------------------------------------------------
# Subcommands
# --------------------------------------------------------------------------------------------


def _read_inputs(aj, files: list[Path], forced: str | None, alpha: float | None):
    """Read and plan every input; one bad file fails the run before any work, naming them all."""
    from abrdf_jax import io

    samples, plans, bad = [], [], []
    for f in files:
        try:
            s = io.read_samples_csv(f)
            plans.append(_plan(aj, s, forced, alpha, f))
            samples.append(s)
        except InputError as e:
            bad.append((f, str(e)))
    if bad:
        others = ", ".join(str(f) for f, _ in bad[1:4]) + (", ..." if len(bad) > 4 else "")
        more = f" (also bad: {others}; nothing was written)" if len(bad) > 1 else ""
        raise InputError(bad[0][1] + more)
    for f, s in zip(files, samples):
        _warn_negative(f, s)
    return samples, plans


def _warn_negative(path: Path, samples) -> None:
    """Negative values are kept (dark-frame noise); say so, since the output is clamped at 0."""
    import numpy as np

    rgb = np.asarray(samples.rgb)
    neg = rgb < 0
    if neg.any():
        row = int(np.argmax(neg.any(axis=1)))
        print(f"{PROG}: warning: {path}: {int(neg.any(axis=1).sum())} of {len(rgb)} samples have negative "
              f"values (min {rgb.min():.3g}, first in data row {row + 1}); kept as measured, the "
              f"reconstruction is clamped at 0", file=sys.stderr)


def _warn_guard(path: Path, samples, config, params, params_file) -> None:
    """Say when the RBF system was ill-conditioned and its regularisation raised (docs/stability.md).

    Only parameters from a file can trigger it: the presets' systems are fixed (protocol pairs,
    tuned widths and λ) and well conditioned in float32 (tests/test_stability.py), so the extra
    compile is skipped for them.
    """
    from abrdf_jax._pipeline import solve_info

    if params_file is None:
        return
    info = solve_info(samples, config, params)
    if int(info.retries) or not bool(info.ok):
        state = "raised" if bool(info.ok) else "raised, still ill-conditioned"
        print(f"{PROG}: warning: {path}: the RBF system is singular to working precision at the requested "
              f"regularisation; regularisation {state} to {float(info.reg):.3g} (condition ~{float(info.cond):.2g})",
              file=sys.stderr)


def cmd_reconstruct(args) -> int:
    import numpy as np

    import abrdf_jax as aj
    from abrdf_jax import io
    from abrdf_jax._pipeline import check_finite

    files, folder_mode = _expand_inputs(args.inputs)
    out = Path(args.output)
    if folder_mode:
        ext = "." + (args.format or "npz")
        if out.exists() and not out.is_dir():
            raise InputError(f"{out}: several inputs need an output folder, but this is a file")
        if not out.exists() and not out.parent.is_dir():
            raise InputError(f"{out}: parent folder {out.parent} does not exist")
        where = out if out.exists() else out.parent
        if not os.access(where, os.W_OK | os.X_OK):
            raise InputError(f"{out}: folder {where} is not writable")
        stems: dict[str, Path] = {}
        for f in files:
            if f.stem in stems:
                raise InputError(f"{f}: same name as {stems[f.stem]}; outputs would collide in {out}")
            stems[f.stem] = f
        targets = [out / (f.stem + ext) for f in files]
    else:
        _check_output_file(out, TABLE_EXTENSIONS, "table")
        if args.format and out.suffix.lower() != "." + args.format:
            raise InputError(f"{out}: extension disagrees with --format {args.format}")
        targets = [out]

    from ._model import check_arguments, choose_all, describe, model_json_path, save, summary

    check_arguments(args)
    # Read and check every input before computing or writing anything.
    forced = "iso102" if args.isotropic else "aniso204" if args.anisotropic else None
    samples, plans = _read_inputs(aj, files, forced, args.alpha)
    choices = choose_all(aj, samples, plans, files, args, forced, quiet=args.quiet)  # --model (auto: select)

    if not folder_mode:
        budget, alpha = plans[0]
        config, params = choices[0]["config"], choices[0]["params"]
        _warn_guard(files[0], samples[0], config, params, args.params)
        table = np.asarray(aj.reconstruct(samples[0], config, params))
        check_finite(table, str(files[0]))
        io.write_table(out, table)
        how = f"parameters from {args.params}" if args.params else f"model {choices[0]['name']}"
        print(f"{out}: reconstructed from {len(samples[0])} samples ({config.budget}, alpha {alpha:g} deg, {how})")
        print("\n".join(describe(choices[0])))
        print(f"model record: {save(model_json_path(out, False), choices, False)}")
        return 0

    from tqdm import tqdm

    out.mkdir(exist_ok=True)
    groups: dict[tuple, list[int]] = {}
    for k, plan in enumerate(plans):
        groups.setdefault((*plan, choices[k]["config"]), []).append(k)
    failed: list[str] = []
    with tqdm(total=len(files), desc="reconstruct", unit="file", file=sys.stderr,
              disable=args.quiet, dynamic_ncols=True) as bar:
        for (budget, alpha, config), members in groups.items():
            params = choices[members[0]]["params"]
            _warn_guard(files[members[0]], samples[members[0]], config, params, args.params)
            for start in range(0, len(members), _CHUNK):
                chunk = members[start:start + _CHUNK]
                tables = np.asarray(aj.reconstruct_batch([samples[k] for k in chunk], config, params))
                for k, table in zip(chunk, tables):
                    try:
                        check_finite(table, str(files[k]))
                    except InputError as e:  # never write it; the other materials are still written
                        failed.append(str(e))
                        continue
                    io.write_table(targets[k], table)
                bar.update(len(chunk))
    budgets = sorted({c["config"].budget for c in choices})
    print(f"{out}: wrote {len(files) - len(failed)} tables ({', '.join(budgets)}; models {summary(choices)})")
    print(f"model record: {save(model_json_path(out, True), choices, True)}")
    if failed:
        for msg in failed:
            print(f"{PROG}: error: {msg}", file=sys.stderr)
        print(f"{PROG}: error: {len(failed)} of {len(files)} reconstructions were not finite; no table was written for them",
              file=sys.stderr)
        return 2
    return 0


def _load_source(aj, source: str):
    """A table file (``.npz``/``.exr``) or a material name."""
    from abrdf_jax import io

    p = Path(source)
    if p.suffix.lower() == ".binary":  # a MERL BRDF file
        return io.MERLMaterial(io.read_merl_binary(p)), None
    if p.suffix.lower() in TABLE_EXTENSIONS or p.exists():
        return io.read_table(p), None
    from abrdf_jax import materials

    try:
        return materials.get_material(source), source
    except InputError as e:
        raise InputError(f"{source}: not a table file (.npz/.exr) nor a known material: {e}") from e


def _default_budget(name: str | None) -> str:
    """The budget for sampling: iso102 for a material known to be isotropic, else aniso204."""
    if name is None:
        return "aniso204"
    try:
        from abrdf_jax import materials

        info = materials.material_info(name)
    except Exception:  # noqa: BLE001 - no information: measure everything
        return "aniso204"
    iso = info.get("isotropic") if isinstance(info, dict) else getattr(info, "isotropic", None)
    return "iso102" if iso is True else "aniso204"


def cmd_sample(args) -> int:
    import abrdf_jax as aj
    from abrdf_jax import io

    out = _check_output_file(Path(args.output), (".csv",), "measurement")
    source, name = _load_source(aj, args.source)
    merl = Path(args.source).suffix.lower() == ".binary"  # MERL data are isotropic
    budget = args.budget or ("iso102" if merl else _default_budget(name))
    alpha = 15.0 if args.alpha is None else float(args.alpha)
    config, params = _params_for(aj, budget, alpha)
    samples = aj.sample(source, config, params)
    io.write_samples_csv(out, samples)
    print(f"{out}: {len(samples)} samples ({budget}, alpha {alpha:g} deg) of {args.source}")
    return 0


_METRIC_ROWS = (("de76", "dE76", ""), ("de2000", "dE2000", ""), ("rmse8", "RMSE8", ""),
                ("psnr", "PSNR", " dB"), ("logerr", "LogErr", ""))


def cmd_evaluate(args) -> int:
    from abrdf_jax import io, metrics

    rec = io.read_table(args.rec)
    ref = io.read_table(args.ref)
    m = _metrics_floats(metrics.evaluate(rec, ref))
    if args.json:
        doc = {"rec": str(args.rec), "ref": str(args.ref)}
        doc.update({k: _finite_or_none(v) for k, v in m.items()})
        print(json.dumps(doc, indent=2))
    else:
        print(f"{'metric':<8} {'value':>10}")
        for key, label, unit in _METRIC_ROWS:
            print(f"{label:<8} {m[key]:>10.4g}{unit}")
    return 0


def cmd_demo(args) -> int:
    from .demo import run_demo

    if args.materials is not None and args.materials < 1:
        raise InputError(f"--materials must be at least 1, got {args.materials}")
    path = run_demo(args.output, n_materials=args.materials, stream=sys.stdout)
    print(f"figure: {path}")
    return 0


def cmd_materials(args) -> int:
    from abrdf_jax import materials

    names = list(materials.material_names())
    width = max((len(n) for n in names), default=4)
    for name in names:
        try:
            info = materials.material_info(name)
        except Exception:  # noqa: BLE001 - listing should not fail on one entry
            info = None
        if isinstance(info, dict):
            desc = info.get("description") or info.get("summary") or ""
            iso = info.get("isotropic")
            kind = "" if iso is None else ("isotropic" if iso else "anisotropic")
            text = "  ".join(x for x in (kind, str(desc)) if x)
        elif info is None:
            text = ""
        else:
            text = str(info)
        print(f"{name:<{width}}  {text}".rstrip())
    print("(also nbrdf:<merl-name> for the neural MERL fits in the shared data)")
    return 0


# --------------------------------------------------------------------------------------------
# Parser and entry point
# --------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="show a traceback on error")

    p = argparse.ArgumentParser(
        prog=PROG, parents=[common],
        description="Reconstruct a material's full ABRDF (81x81 light x view directions, RGB) from "
        "sparse slice measurements (Filip, ICPR 2012).",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser("reconstruct", parents=[common], help="measurement CSV -> ABRDF table",
                       description="Reconstruct ABRDF tables from measurement CSV files. One input: "
                       "-o names the output file (.npz or .exr). Several inputs or a folder: -o names "
                       "an output folder (created if missing), one table per input.")
    r.add_argument("inputs", nargs="+", metavar="MEAS", help="measurement CSV file(s) or a folder of them")
    r.add_argument("-o", "--output", required=True, metavar="OUT", help="output table (.npz/.exr) or folder")
    g = r.add_mutually_exclusive_group()
    g.add_argument("--isotropic", action="store_true", help="use only the diagonal slices (iso102)")
    g.add_argument("--anisotropic", action="store_true", help="use all 8 slices (aniso204)")
    r.add_argument("--alpha", type=float, metavar="DEG", help="slice offset (default: read off the data)")
    r.add_argument("--format", choices=("npz", "exr"), help="table format in folder mode (default npz)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--preset", choices=("recommended", "paper"), default="recommended",
                   help="recommended: log-value RBF chosen on the MERL train split (default); "
                        "paper: Filip 2012 as published (linear values)")
    r.add_argument("--params", metavar="PARAMS.json", type=Path,
                   help="fitted configuration and parameters from 'abrdf-jax fit' (overrides --preset)")
    from ._model import add_arguments as add_model_arguments

    add_model_arguments(r)  # --model auto|NAME, --tol, --noise
    r.set_defaults(func=cmd_reconstruct)

    s = sub.add_parser("sample", parents=[common], help="table or material -> measurement CSV",
                       description="Take the protocol's slice samples of a dense table (.npz/.exr), "
                       "a MERL BRDF file (.binary, nearest bin) or a built-in material model.")
    s.add_argument("source", metavar="SOURCE", help="TABLE.npz, TABLE.exr, a MERL FILE.binary or a material name")
    s.add_argument("-o", "--output", required=True, metavar="MEAS.csv")
    s.add_argument("--budget", choices=BUDGETS,
                   help="iso102 (4 diagonal slices) or aniso204 (8 slices); default: iso102 for a "
                   "material known to be isotropic, else aniso204")
    s.add_argument("--alpha", type=float, metavar="DEG", help="slice offset in degrees (default 15)")
    s.set_defaults(func=cmd_sample)

    e = sub.add_parser("evaluate", parents=[common], help="protocol metrics of a reconstruction",
                       description="Compare a reconstructed table with a reference (PROTOCOL.md metrics).")
    e.add_argument("rec", metavar="REC", help="reconstructed table (.npz/.exr)")
    e.add_argument("ref", metavar="REF", help="reference table (.npz/.exr); sets the exposure")
    e.add_argument("--json", action="store_true", help="print JSON (non-finite values as null)")
    e.set_defaults(func=cmd_evaluate)

    d = sub.add_parser("demo", parents=[common], help="sample, reconstruct and evaluate built-in materials",
                       description="Sample -> reconstruct -> evaluate a few built-in materials, print a "
                       "table and save a comparison figure.")
    d.add_argument("-o", "--output", default="abrdf_demo.png", metavar="FIGURE.png")
    d.add_argument("--materials", type=int, metavar="N", help="number of materials (default: all demo ones)")
    d.set_defaults(func=cmd_demo)

    m = sub.add_parser("materials", parents=[common], help="list the built-in materials")
    m.set_defaults(func=cmd_materials)

    from .fit import register as register_fit

    register_fit(sub)
    from .btf import register as register_btf

    register_btf(sub)
    return p


def _describe(exc: BaseException) -> str:
    if isinstance(exc, OSError) and not isinstance(exc, InputError):
        name = exc.filename
        reason = exc.strerror or str(exc)
        return f"{name}: {reason}" if name else reason
    return str(exc) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 success, 2 bad input, 130 interrupted)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a usage error already printed by argparse
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    verbose = getattr(args, "verbose", False)
    try:
        return int(args.func(args) or 0)
    except (InputError, ValueError, OSError) as e:
        # Bad input; a ValueError from deeper down is a user-visible condition too (e.g. an
        # option combination the method rejects). -v shows where it came from.
        if verbose:
            traceback.print_exc()
        print(f"{PROG}: error: {_describe(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
