"""``abrdf-jax reconstruct``: measurement CSV file(s) → ABRDF table(s), and which model made each.

Each input is read and grouped into slices once (:class:`abrdf_jax.Measurements`); the model
choice and the reconstruction both take those slices. ``--model auto`` runs
:func:`abrdf_jax.select.select_model` on every input (the isotropy test on the axial slices; an
isotropic material gets the bivariate model, an anisotropic one the candidate that held-out
errors and the tolerance rule choose); ``--model NAME`` fixes a model. The choice, the
candidates' held-out errors and the reason are printed and saved beside the output
(``OUT.model.json``, one for an output folder). ``--isotropic``/``--anisotropic`` force the
budget. Several inputs are reconstructed in batches.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from .._errors import InputError
from .._names import DIRECT_MODELS, MODEL_TOL, MODELS, PRESETS, TABLE_SUFFIXES
from . import _common as common

#: Every model ``--model`` can fix: the RBF candidates, the learned and the direct models.
FIXED_MODELS = (*MODELS, *DIRECT_MODELS)
#: Threads writing the finished tables while the next batch computes.
WRITERS = 2
#: Tables a writer task writes (:func:`abrdf_jax.io.write_tables`).
WRITE_CHUNK = 32
#: A folder run rewrites its model record after a batch when this many seconds have passed
#: since the last rewrite (and at the end): an interrupted run loses at most this much of the
#: record, whose tables --resume then redoes.
RECORD_EVERY = 2.0
FORMATS = [s.lstrip(".") for s in TABLE_SUFFIXES]
#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "measurement CSV -> ABRDF table",
    "description": "Reconstruct ABRDF tables from measurement CSV files. One input: -o names the "
    "output file (.npz or .exr). Several inputs or a folder: -o names an output folder (created "
    "if missing), one table per input. The model is chosen per input (--model auto) unless "
    "--model, --preset or --params fixes it.",
    "inputs": "measurement CSV file(s) or a folder of them",
    "--output": "output table (.npz/.exr) or folder",
    "--alpha": "slice offset (default: read off the data)",
    "--format": "table format in folder mode (default npz)",
    "--quiet": "no progress bar",
    "--preset": "fix the model to a " + common.preset_help(None) + ". Without --preset, --model or "
    "--params the model is chosen automatically (--model auto)",
    "--params": "fitted configuration and parameters from 'abrdf-jax fit' (fixes the model)",
    "--model": "auto (default: isotropy test; an isotropic material gets the bivariate model, an "
    "anisotropic one the simplest candidate within --tol of the best held-out error) or a fixed "
    "model: " + ", ".join(FIXED_MODELS),
    "--tol": f"tolerance of the automatic choice, relative (default {MODEL_TOL:g})",
    "--resume": "folder mode: keep the tables of an earlier (interrupted) run that are complete "
    "and named in its model record; reconstruct only the others (the same tables, bit for bit, "
    "as one uninterrupted run)",
    "--cache-dir": common.CACHE_DIR_HELP,
    "--prior": "the prior of --model prior|fused and of the automatic choice: a prior file "
    "('abrdf-jax prior train') or 'default' (the built-in prior, from the package's own analytic "
    "materials; what --model prior|fused use without --prior). With --model auto, --prior adds "
    "the prior-only and the fused (prior + kernel) model to the candidates (docs/prior.md)",
    "--overwrite": "folder mode: replace an output folder written with other settings (model, "
    "preset, parameters, prior, tolerance, budget, alpha, format); without it such a folder is "
    "refused",
    "--noise": "relative noise of one sample for the isotropy test (default: estimated from the "
    "data)",
    "--uncertainty": common.UNCERTAINTY_HELP,
}


def register(sub) -> None:
    r = common.command(sub, "reconstruct", run, HELP["help"], HELP["description"], writes=True)
    add = common.adder(r, HELP)
    add("inputs", nargs="+", metavar="MEAS")
    add("-o", "--output", required=True, metavar="OUT")
    common.budget_flags(r)
    add("--alpha", type=common.alpha_deg, metavar="DEG")
    add("--format", choices=FORMATS)
    add("-q", "--quiet", action="store_true")
    add("--preset", choices=PRESETS)
    add("--params", metavar="PARAMS.json", type=common.existing("file"))
    add("--model", metavar="MODEL")
    add("--tol", type=common.finite("--tol", 0.0, open_low=False), metavar="FRAC")
    add("--noise", type=common.finite("--noise", 0.0, open_low=False), metavar="SIGMA")
    add("--prior", metavar="FILE")
    add("--resume", action="store_true")
    add("--overwrite", action="store_true")
    add("--uncertainty", action="store_true")
    add("--cache-dir", metavar="DIR")


# --------------------------------------------------------------------------------------------
# The model of each input
# --------------------------------------------------------------------------------------------


def check_model_arguments(args) -> None:
    """Fail before any work on contradictory model options."""
    fixed = None if args.model == "auto" else args.model
    if fixed is not None and fixed not in FIXED_MODELS:
        names = ", ".join(FIXED_MODELS)
        raise InputError(f"unknown model {fixed!r}; choose auto or one of: {names}")
    given = {"model": fixed, "preset": args.preset, "params": args.params}
    fixing = [f"--{k} {v}" for k, v in given.items() if v is not None]
    if len(fixing) > 1:
        raise InputError(f"{fixing[0]} and {fixing[1]} both fix the model; give one")
    if args.model == "auto" and fixing:
        raise InputError(f"--model auto chooses the model, but {fixing[0]} fixes it; give one")
    for name, v, what in (("tol", args.tol, "a fraction"), ("noise", args.noise, "a level")):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise InputError(f"--{name} must be {what} >= 0, got {v}")
    common.check_prior_arguments(args)
    skip = (None, *common.LEARNED_MODELS, *DIRECT_MODELS)  # their budget follows the data
    if fixed not in skip and (args.isotropic or args.anisotropic):
        from ..select import candidate  # the candidate's budget (imports the numerics)

        iso = candidate(fixed).settings["budget"] == "iso102"
        if args.anisotropic and iso:
            raise InputError(f"--model {fixed} is isotropic (iso102) but --anisotropic was given")
        if args.isotropic and not iso:
            why = "needs the axial slices (aniso204) but --isotropic was given"
            raise InputError(f"--model {fixed} {why}")


def choose(item: common.Measured, args, forced: str | None, caches: "common.Caches") -> dict:
    """The model for one measurement (see :func:`abrdf_jax.cli._common.model_choice`).

    A fixed model, a preset and an automatic choice left with one candidate need no JAX
    (:func:`abrdf_jax.select.quick_selection`); a parameter file and a comparison of candidates
    by held-out errors do (``caches.numerics()`` first)."""
    from .._config import default_values, preset
    from ..select._candidates import CANDIDATES, candidate

    where, budget, alpha = item.path, item.budget, item.alpha
    if args.params is not None:
        caches.numerics()
        config, params = common.params_for(budget, alpha, params_file=args.params)
        why = f"parameters and model fixed by {args.params}"
        return common.model_choice(where, None, config, params, "params", why)
    if _automatic(args):
        return _auto_choices([item], args, forced, caches)[0]
    if args.model in common.LEARNED_MODELS:
        return common.learned_choice(item, caches.prior, args.model, budget, "fixed")
    if args.model in DIRECT_MODELS:
        return common.bivariate_choice(item, budget)
    if args.preset is not None:
        config, how, flag = preset(args.preset, budget), "preset", f"--preset {args.preset}"
        c = next((c for c in CANDIDATES.values() if c.config() == config), None)  # its name, if any
    else:
        c = candidate(args.model)
        if c.settings["budget"] == "aniso204" and budget != "aniso204":
            why = "needs axial slices (aniso204), but the measurement has none"
            raise InputError(f"{where}: --model {args.model} {why}")
        config, how, flag = c.config(), "fixed", f"--model {c.name}"
    params = default_values(config, alpha)
    if c is None:
        why = f"{flag}: {common.PRESET_HELP[args.preset]}"
        return common.model_choice(where, args.preset, config, params, how, why)
    why = f"{flag}: {c.description}"
    return common.model_choice(where, c.name, config, params, how, why, {"rank": c.rank})


def _auto_choices(items, args, forced, caches, on_done=None) -> list[dict]:
    """The automatic choice of every input: without JAX where one candidate is left or the
    held-out errors are matrices in the operator store (``abrdf_jax.select._held_out_entry``,
    and ``_learned_entry`` for the prior's models: a single file, or a layout shared by
    ``MIN_GROUP`` inputs), else by held-out errors in JAX,
    the folds of several inputs in batches (:func:`abrdf_jax.select.select_models`). The same
    choices either way (errors within float32 rounding)."""
    from ..select import LEVEL, MIN_EFFECT, TOL
    from ..select._held_out_entry import MIN_GROUP, entry_selections
    from ..select._isotropy import isotropy_tests

    reports = None  # the isotropy tests (and their noise estimates), a layout's files at once
    if forced is None:
        reports = isotropy_tests(
            [it.meas for it in items], noise=args.noise, level=LEVEL, min_effect=MIN_EFFECT
        )
    tol = {} if args.tol is None else {"tol": args.tol}
    sels = entry_selections(
        [(it.meas, it.alpha) for it in items],
        store=caches.store,
        warn=common.warn,
        budget=forced,
        tol=TOL if args.tol is None else args.tol,
        noise=args.noise,
        level=LEVEL,
        min_effect=MIN_EFFECT,
        min_group=1 if len(items) == 1 else MIN_GROUP,
        lone=common.lone_of(items[0]) if len(items) == 1 else None,
        before_build=caches.numerics,
        where=[it.path for it in items],
        learned=caches.prior,
        reports=reports,
        prefetch=caches.prefetch,
    )
    rest = [k for k, s in enumerate(sels) if s is None]
    if rest:
        caches.numerics()
        from ..select import select_model, select_models

        kw = dict(budget=forced, noise=args.noise, **tol)
        if caches.prior is not None:
            kw["prior"] = caches.prior.load()

        def one(it):
            try:
                return select_model(it.meas, alpha_deg=it.alpha, **kw)
            except InputError as e:
                raise InputError(f"{it.path}: {e}") from e

        found = None
        if len(rest) > 1:
            try:
                alphas = [items[k].alpha for k in rest]
                found = select_models([items[k].meas for k in rest], alpha_deg=alphas, **kw)
            except InputError:
                pass  # one by one below, so that the error names its file
        found = found or [one(items[k]) for k in rest]
        for k, s in zip(rest, found):
            sels[k] = s
    if on_done is not None:
        on_done(len(items))
    return [_auto_choice(it, s, caches.prior) for it, s in zip(items, sels)]


def _automatic(args) -> bool:
    return args.params is None and args.preset is None and args.model in (None, "auto")


def _auto_choice(item, s, prior) -> dict:
    """The model record of an automatic choice (a :class:`abrdf_jax.select.Selection`)."""
    extra = {"rank": s.ranks[s.name], "tol": s.tol, "folds": s.k}
    extra |= {**s.evidence(), "seconds": s.seconds}
    if s.name in common.LEARNED_MODELS:
        return common.learned_choice(item, prior, s.name, s.config.budget, "auto", s.reason, extra)
    if s.name in DIRECT_MODELS:
        return common.bivariate_choice(item, s.config.budget, "auto", s.reason, extra)
    return common.model_choice(item.path, s.name, s.config, s.params, "auto", s.reason, extra)


def choose_all(
    items: list[common.Measured], args, forced: str | None, caches: "common.Caches", quiet=False
) -> list[dict]:
    """:func:`choose` for every input, with a progress bar when there are several."""
    quiet = quiet or args.quiet or len(items) < 2
    with common.progress(len(items), "select model", quiet) as bar:
        if _automatic(args):
            out = _auto_choices(items, args, forced, caches, on_done=bar.update)
        else:
            out = []
            for item in items:
                out.append(choose(item, args, forced, caches))
                bar.update(1)
    found = common.smoothing_records(items, [c.get("config") for c in out])
    for item, choice, smoothing in zip(items, out, found):
        choice["record"]["measurement"] = item.used  # what of the file was used, and why not
        if smoothing is not None:
            choice["record"]["smoothing"] = smoothing
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
    common.check_output_folder(out)
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
    common.check_uncertainty(args, folder_mode)
    prior = common.prior_source(args)  # a bad prior file fails here, before any work
    common.check_params_file(args.params)  # and a bad parameter file
    # One writer of the output (and its model record) at a time; a killed one's lock is taken
    # over and its temporary files removed (docs/stability.md, "Faults"); said at the write.
    # One BLAS thread, set before numpy's import and the readers' fork (cli/_blas.py).
    record = out.parent / ((out.name if folder_mode else out.stem) + ".model.json")
    also = [record] + ([common.std_path(out)] if args.uncertainty else [])
    with common.one_blas_thread(), common.output_lock(out, also=also, announce=False):
        return _run(args, files, targets, out, folder_mode, prior)


def folder_settings(args) -> dict:
    """What decides a folder run's tables besides its inputs (the model record's ``settings``):
    a rerun into the folder with other settings is refused unless ``--overwrite``."""
    params = None if args.params is None else str(args.params)
    keys = ("model", "preset", "tol", "noise", "prior", "isotropic", "anisotropic", "alpha")
    settings = {k: getattr(args, k) for k in keys} | {
        "params": params,
        "format": args.format or FORMATS[0],
    }
    return settings | {"model": args.model or "auto"}  # no --model is --model auto


def _run(args, files, targets, out, folder_mode, prior) -> int:
    resumed, all_files = [], files
    if args.overwrite and not folder_mode:
        raise InputError("--overwrite is for an output folder; an output file is always replaced")
    settings = folder_settings(args) if folder_mode else None
    same = folder_mode and common.folder_settings_check(
        out.parent / (out.name + ".model.json"), settings, args.overwrite
    )
    if args.resume:
        if not folder_mode:
            raise InputError("--resume needs an output folder (several inputs or a folder)")
        if same:
            files, targets, resumed = common.resumable(files, targets, out)
        if not files:
            print(f"{out}: all {len(resumed)} tables are complete (--resume); nothing to do")
            return 0
    # Read and check every input before computing or writing anything.
    forced = common.forced_budget(args)
    caches: list[common.Caches] = []
    before = lambda: caches.append(common.Caches(args.cache_dir, common.warn))  # noqa: E731
    place = {str(f): k for k, f in enumerate(all_files)}  # each input's place in the job
    blocks = common.input_blocks(
        files, targets, forced, args.alpha, before, args.quiet, [place[str(f)] for f in files]
    )
    caches[0].prior = prior
    if folder_mode:
        job = (len(files), out, place, resumed, settings)
        return _reconstruct_folder(blocks, job, args, caches[0], forced)
    ((items, _),) = blocks
    with common.stage(items[0], "choosing the model", args.quiet):
        choices = choose_all(items, args, forced, caches[0])
    with common.stage(items[0], f"reconstructing with {choices[0]['name']}", args.quiet):
        return _reconstruct_one(items[0], choices[0], out, args, caches[0])


def _reconstruct_one(item: common.Measured, choice: dict, out: Path, args, caches) -> int:
    import numpy as np

    from .. import io
    from .._arrays import check_finite
    from .._engine import plan_job, reconstruct_many

    config, params = choice["config"], choice["params"]
    meas = common.measurements_for(item, config)
    common.warn_guard(item.path, meas, config, params, args.params)
    lone = common.lone_of(item)  # a jittered capture: the shared second stage, no own build
    plan = plan_job([meas], config, min_group=2, small=True, lone=lone) if lone else None
    ((_, tables, engine),) = reconstruct_many(
        [meas], config, params, operator=caches.operator, min_group=1,
        before_jax=caches.numerics, host=True, plan=plan,
    )  # fmt: skip
    table = np.asarray(tables[0])
    check_finite(table, str(item.path))
    common.announce_replace(out)
    io.write_table(out, table)
    choice["record"]["engine"] = engine
    std = common.write_std(item, choice, out, caches.prior) if args.uncertainty else None
    how = f"parameters from {args.params}" if args.params else f"model {choice['name']}"
    print(
        f"{out}: reconstructed from {len(item.samples)} samples ({config.budget}, alpha "
        f"{item.alpha:g} deg, {how})"
    )
    print("\n".join(common.describe(choice)))
    if std is not None:
        print(f"uncertainty: {std} (standard deviation of ln(x cos(theta_v) + eps); docs/prior.md)")
    print(f"model record: {common.save_model_record(out, [choice], False)}")
    return 0


def _reconstruct_folder(blocks, job: tuple, args, caches, forced) -> int:
    """Every input through :func:`abrdf_jax._engine.reconstruct_many` (operator groups and
    padded pipeline batches), block by block (:func:`common.input_blocks`), each batch's tables
    written by a small thread pool while the next batch computes, the folder's model record
    rewritten (atomically) after every batch: an interrupted run keeps every table it
    finished, and the record lists only those. Memory: one block and ~2 KiB a finished file.
    ``job``: the files to do now, the output folder, each input's place in the whole job
    (``--resume`` keeps the batches' rows), the records ``--resume`` kept, the settings."""
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    from .. import io
    from .._arrays import check_finite
    from .._engine import SharedStages, reconstruct_many

    n_files, out, place, resumed, settings = job
    out.mkdir(exist_ok=True)
    kept = common.kept_batches(resumed, place)
    failed: list[str] = []
    done = [common.compact(c) for c in resumed]  # records of the outputs --resume kept
    paths, models, budgets = {"operator": 0, "pipeline": 0}, [], set()
    with (
        common.progress(n_files, "reconstruct", args.quiet) as bar,
        ThreadPoolExecutor(max_workers=WRITERS) as pool,
        caches.prefetch,  # the builds on a second thread (cli/_prefetch.py) end with the run
    ):
        pending: list = []  # (futures, records) of the batch being written
        saved = [time.perf_counter()]

        def settle(final=False):
            for futures, records in pending:
                for f in futures:
                    f.result()  # a write error ends the run (nothing partial: atomic writes)
                done.extend(map(common.compact, records))
            pending.clear()
            # the record of a big folder is large: rewritten at most every RECORD_EVERY s
            if final or time.perf_counter() - saved[0] >= RECORD_EVERY:
                common.save_model_record(out, done, True, settings)
                saved[0] = time.perf_counter()

        for items, targets in blocks:
            bar.set_description("select model")
            choices = choose_all(items, args, forced, caches, quiet=True)
            bar.set_description("reconstruct")
            models += [c["record"]["model"] for c in choices]
            budgets |= {c["config"].budget for c in choices}
            jobs = common.block_jobs(
                items, choices, place, kept, block=common.BLOCK, slices=common.measurements_for
            )
            stages = SharedStages()  # jittered captures' second stages: one product
            caches.prefetch.operators(jobs, lambda m, c=choices: c[m[0]]["params"])

            def take(members, idx, tables, path, items=items, targets=targets, choices=choices):
                paths[path] += len(idx)
                records, paths_, tables_ = [], [], []
                finite = np.isfinite(tables).reshape(len(idx), -1).all(axis=1)  # one pass
                for j, table, ok in zip(idx, tables, finite):
                    k = members[j]
                    try:
                        if not ok:  # raises, naming the file and the first bad value
                            check_finite(table, str(items[k].path))
                    except InputError as e:  # never written; the other materials still are
                        failed.append(str(e))
                        continue
                    paths_.append(targets[k])
                    tables_.append(table)
                    choices[k]["record"]["engine"] = path
                    records.append(choices[k])
                # atomic, not fsync-ed: --resume reads every table it keeps (docs/cache.md);
                # a task per WRITE_CHUNK tables (a future per table cost more than its write)
                futures = [
                    pool.submit(
                        io.write_tables, paths_[a : a + WRITE_CHUNK], tables_[a : a + WRITE_CHUNK]
                    )
                    for a in range(0, len(paths_), WRITE_CHUNK)
                ]
                settle()  # the previous batch's files are complete before the record names them
                pending.append((futures, records))
                bar.update(len(idx))

            for config, members, meas, job in jobs:
                params = choices[members[0]]["params"]
                common.warn_guard(items[members[0]].path, meas[0], config, params, args.params)
                for idx, tables, path in reconstruct_many(
                    meas,
                    config,
                    params,
                    operator=caches.operator,
                    before_jax=caches.numerics,
                    host=True,
                    stages=stages.tagged(members),
                    **job,
                ):
                    take(members, idx, tables, path)
                if stages.full:
                    for tag, idx, tables in stages.flush():
                        take(tag, idx, tables, "operator")
            for tag, idx, tables in stages.flush():  # a block's members: its own indices
                take(tag, idx, tables, "operator")
        settle(final=True)
    n = n_files + len(resumed)
    engines = ", ".join(f"{v} by the {k}" for k, v in paths.items() if v)
    kept = f", {len(resumed)} kept (--resume)" if resumed else ""
    print(
        f"{out}: wrote {n_files - len(failed)} tables{kept} ({', '.join(sorted(budgets))}; "
        f"{engines}; models {common.summary(models)})"
    )
    print(f"model record: {common.save_model_record(out, done, True, settings)}")
    for msg in failed:
        common.say(f"error: {msg}")
    if failed:
        common.say(
            f"error: {len(failed)} of {n} reconstructions were not finite; no table was "
            "written for them"
        )
    return 2 if failed else 0
