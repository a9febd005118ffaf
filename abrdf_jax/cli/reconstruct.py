"""``abrdf-jax reconstruct``: measurement CSV file(s) → ABRDF table(s), and which model made each.

One input: ``-o`` names the output file (``.npz``/``.exr``). Several inputs or a folder: ``-o``
names an output folder, one table per input, reconstructed in batches. Each input is read and
grouped into slices once (:class:`abrdf_jax.Measurements`); the model choice and the
reconstruction both take those slices.

The model: ``--model auto`` (the default when neither ``--model``, ``--preset`` nor ``--params``
is given) runs :func:`abrdf_jax.select.select_model` on every input (the isotropy test on the axial
slices, then held-out errors with the tolerance rule); ``--model NAME`` fixes a candidate of
``abrdf_jax.select.CANDIDATES``; ``--preset NAME`` fixes ``abrdf_jax.preset(NAME, budget)``;
``--params PARAMS.json`` fixes the configuration and parameters of a fitted file. The choice, the
candidates' held-out errors and the reason are printed and saved beside the output
(``OUT.model.json``; for an output folder ``OUT/``, one ``OUT.model.json`` beside it holding every
input's entry). ``--isotropic``/``--anisotropic`` force the budget: ``auto`` then chooses among
that budget's candidates only.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

from .._errors import InputError
from .._names import MODEL_TOL, MODELS, PRESETS, TABLE_SUFFIXES
from . import _common as common

#: Materials per batched reconstruction call (bounds memory, drives the progress bar).
CHUNK = 32


def register(sub) -> None:
    """Add the ``reconstruct`` subcommand to the ``abrdf-jax`` parser."""
    r = sub.add_parser("reconstruct", parents=[common.verbose_parent()], help="measurement CSV -> ABRDF table",
                       description="Reconstruct ABRDF tables from measurement CSV files. One input: "
                       "-o names the output file (.npz or .exr). Several inputs or a folder: -o names "
                       "an output folder (created if missing), one table per input. The model is chosen "
                       "per input (--model auto) unless --model, --preset or --params fixes it.")
    r.add_argument("inputs", nargs="+", metavar="MEAS", help="measurement CSV file(s) or a folder of them")
    r.add_argument("-o", "--output", required=True, metavar="OUT", help="output table (.npz/.exr) or folder")
    g = r.add_mutually_exclusive_group()
    g.add_argument("--isotropic", action="store_true", help="use only the diagonal slices (iso102)")
    g.add_argument("--anisotropic", action="store_true", help="use all 8 slices (aniso204)")
    r.add_argument("--alpha", type=float, metavar="DEG", help="slice offset (default: read off the data)")
    r.add_argument("--format", choices=[s.lstrip(".") for s in TABLE_SUFFIXES],
                   help="table format in folder mode (default npz)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--preset", choices=PRESETS, default=None,
                   help="fix the model to a " + common.preset_help(None)
                   + ". Without --preset, --model or --params the model is chosen automatically (--model auto)")
    r.add_argument("--params", metavar="PARAMS.json", type=Path,
                   help="fitted configuration and parameters from 'abrdf-jax fit' (fixes the model)")
    r.add_argument("--model", metavar="MODEL", default=None,
                   help="auto (default: isotropy test, then the simplest candidate within --tol of the best "
                        "held-out error) or a fixed model: " + ", ".join(MODELS))
    r.add_argument("--tol", type=float, default=None, metavar="FRAC",
                   help=f"tolerance of the automatic choice, relative (default {MODEL_TOL:g})")
    r.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                   help="relative noise of one sample for the isotropy test (default: estimated from the data)")
    r.set_defaults(func=run)


# --------------------------------------------------------------------------------------------
# The model of each input
# --------------------------------------------------------------------------------------------


def check_model_arguments(args) -> None:
    """Fail before any work on contradictory model options."""
    if args.model is not None and args.model != "auto" and args.model not in MODELS:
        raise InputError(f"unknown model {args.model!r}; choose auto or one of: {', '.join(MODELS)}")
    fixed = None if args.model == "auto" else args.model
    fixing = [f"--{k} {v}" for k, v in (("model", fixed), ("preset", args.preset), ("params", args.params))
              if v is not None]
    if len(fixing) > 1:
        raise InputError(f"{fixing[0]} and {fixing[1]} both fix the model; give one")
    if args.model == "auto" and fixing:
        raise InputError(f"--model auto chooses the model, but {fixing[0]} fixes it; give one")
    if args.tol is not None and not (math.isfinite(args.tol) and args.tol >= 0):
        raise InputError(f"--tol must be a fraction >= 0, got {args.tol}")
    if args.noise is not None and not (math.isfinite(args.noise) and args.noise >= 0):
        raise InputError(f"--noise must be a relative level >= 0, got {args.noise}")
    if args.model not in (None, "auto") and (args.isotropic or args.anisotropic):
        from ..select import candidate  # the candidate's budget (imports the numerics)

        budget = candidate(args.model).settings["budget"]
        if args.anisotropic and budget != "aniso204":
            raise InputError(f"--model {args.model} is isotropic (iso102) but --anisotropic was given")
        if args.isotropic and budget != "iso102":
            raise InputError(f"--model {args.model} needs the axial slices (aniso204) but --isotropic was given")


def choose(item: common.Measured, args, forced: str | None) -> dict:
    """The model for one measurement (see :func:`abrdf_jax.cli._common.model_choice`)."""
    import abrdf_jax as aj
    from ..select import CANDIDATES, candidate, select_model

    where, budget, alpha = item.path, item.budget, item.alpha
    if args.params is not None:
        config, params = common.params_for(budget, alpha, params_file=args.params)
        return common.model_choice(where, None, config, params, "params",
                                   f"parameters and model fixed by {args.params}")
    if args.preset is not None:
        config = aj.preset(args.preset, budget)
        params = aj.Params.default(config, alpha_deg=alpha)
        c = next((c for c in CANDIDATES.values() if c.config() == config), None)  # its name, if it has one
        if c is None:
            return common.model_choice(where, args.preset, config, params, "preset",
                                       f"--preset {args.preset}: {common.PRESET_HELP[args.preset]}")
        return common.model_choice(where, c.name, config, params, "preset", f"--preset {args.preset}: {c.description}",
                                   {"rank": c.rank})
    if args.model is not None and args.model != "auto":
        c = candidate(args.model)
        if c.settings["budget"] == "aniso204" and budget != "aniso204":
            raise InputError(f"{where}: --model {args.model} needs axial slices (aniso204), "
                             "but the measurement has none")
        config = c.config()
        params = aj.Params.default(config, alpha_deg=alpha)
        return common.model_choice(where, c.name, config, params, "fixed", f"--model {c.name}: {c.description}",
                                   {"rank": c.rank})
    tol = {} if args.tol is None else {"tol": args.tol}
    try:
        sel = select_model(item.meas, budget=forced, noise=args.noise, alpha_deg=alpha, **tol)
    except InputError as e:
        raise InputError(f"{where}: {e}") from e
    d = sel.to_dict()
    extra = {"rank": CANDIDATES[sel.name].rank, "tol": sel.tol, "folds": sel.k, "candidates": d["candidates"],
             "isotropy": d["isotropy"], "seconds": sel.seconds}
    return common.model_choice(where, sel.name, sel.config, sel.params, "auto", sel.reason, extra)


def choose_all(items: list[common.Measured], args, forced: str | None) -> list[dict]:
    """:func:`choose` for every input, with a progress bar when there are several."""
    from tqdm import tqdm

    out = []
    with tqdm(total=len(items), desc="select model", unit="file", file=sys.stderr,
              disable=args.quiet or len(items) < 2, dynamic_ncols=True) as bar:
        for item in items:
            out.append(choose(item, args, forced))
            bar.update(1)
    return out


# --------------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------------


def _targets(files: list[Path], out: Path, folder_mode: bool, fmt: str | None) -> list[Path]:
    """The output path of every input; fails before any work when they cannot be written."""
    if not folder_mode:
        common.check_output_file(out, TABLE_SUFFIXES, "table")
        if fmt and out.suffix.lower() != "." + fmt:
            raise InputError(f"{out}: extension disagrees with --format {fmt}")
        return [out]
    ext = "." + (fmt or TABLE_SUFFIXES[0].lstrip("."))
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
    return [out / (f.stem + ext) for f in files]


def run(args) -> int:
    files, folder_mode = common.expand_inputs(args.inputs)
    out = Path(args.output)
    targets = _targets(files, out, folder_mode, args.format)
    check_model_arguments(args)
    # Read and check every input before computing or writing anything.
    forced = common.forced_budget(args)
    items = common.read_inputs(files, forced, args.alpha)
    choices = choose_all(items, args, forced)
    if folder_mode:
        return _reconstruct_folder(items, choices, targets, out, args)
    return _reconstruct_one(items[0], choices[0], out, args)


def _reconstruct_one(item: common.Measured, choice: dict, out: Path, args) -> int:
    import numpy as np

    import abrdf_jax as aj
    from .. import io

    config, params = choice["config"], choice["params"]
    meas = common.measurements_for(item, config)
    common.warn_guard(item.path, meas, config, params, args.params)
    table = np.asarray(aj.reconstruct(meas, config, params))
    aj.check_finite(table, str(item.path))
    io.write_table(out, table)
    how = f"parameters from {args.params}" if args.params else f"model {choice['name']}"
    print(f"{out}: reconstructed from {len(item.samples)} samples ({config.budget}, alpha {item.alpha:g} deg, {how})")
    print("\n".join(common.describe(choice)))
    print(f"model record: {common.save_model_record(common.model_json_path(out, False), [choice], False)}")
    return 0


def _reconstruct_folder(items: list[common.Measured], choices: list[dict], targets: list[Path], out: Path,
                        args) -> int:
    import numpy as np
    from tqdm import tqdm

    import abrdf_jax as aj
    from .. import io

    out.mkdir(exist_ok=True)
    groups: dict[tuple, list[int]] = {}
    for k, (item, choice) in enumerate(zip(items, choices)):
        groups.setdefault((item.budget, item.alpha, choice["config"]), []).append(k)
    failed: list[str] = []
    with tqdm(total=len(items), desc="reconstruct", unit="file", file=sys.stderr,
              disable=args.quiet, dynamic_ncols=True) as bar:
        for (_, _, config), members in groups.items():
            params = choices[members[0]]["params"]
            meas = [common.measurements_for(items[k], config) for k in members]
            common.warn_guard(items[members[0]].path, meas[0], config, params, args.params)
            for start in range(0, len(members), CHUNK):
                chunk = members[start:start + CHUNK]
                tables = np.asarray(aj.reconstruct_batch(meas[start:start + CHUNK], config, params))
                for k, table in zip(chunk, tables):
                    try:
                        aj.check_finite(table, str(items[k].path))
                    except InputError as e:  # never write it; the other materials are still written
                        failed.append(str(e))
                        continue
                    io.write_table(targets[k], table)
                bar.update(len(chunk))
    budgets = sorted({c["config"].budget for c in choices})
    n = len(items)
    print(f"{out}: wrote {n - len(failed)} tables ({', '.join(budgets)}; models {common.summary(choices)})")
    print(f"model record: {common.save_model_record(common.model_json_path(out, True), choices, True)}")
    if failed:
        for msg in failed:
            print(f"{common.PROG}: error: {msg}", file=sys.stderr)
        print(f"{common.PROG}: error: {len(failed)} of {n} reconstructions were not finite; no table was written "
              "for them", file=sys.stderr)
        return 2
    return 0
