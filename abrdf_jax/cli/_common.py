"""What the subcommands of ``abrdf-jax`` share: output checks, inputs, presets, warnings, records.

Arrows point into this module only: every subcommand module imports it, none imports another
subcommand, and this module imports no subcommand. It imports no JAX at module level (the
numerics are imported inside the functions that compute), so building the parser, ``--help`` and
every check of an argument or a file that needs no numerics stay free of JAX.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from pathlib import Path
from typing import NamedTuple

from .._errors import InputError
from .._names import check_registry
from ._outputs import (  # noqa: F401 - the outputs' checks and policy, used through this module
    OVERWRITE_POLICY,
    announce_replace,
    check_json_output,
    check_output_file,
    check_output_folder,
    folder_settings_check,
    refused_store,
)
from ._outputs import output_lock as _output_lock
from ._args import (  # noqa: F401 - the arguments' validators, used through this module
    ALPHA_RANGE,
    alpha_deg,
    degrees,
    elevation_pairs,
    existing,
    finite,
    integer,
    int_in,
    output_path,
    positive,
)
from . import _progress
from ._progress import BigFile, progress, stage  # noqa: F401 - used through this module
from ._blas import one_blas_thread  # noqa: F401 - used through this module
from ._malloc import keep_freed_blocks  # noqa: F401 - used through this module
from ._capture_values import value_warnings

PROG = "abrdf-jax"
#: Format tag of the model record written beside a reconstruction (``OUT.model.json``).
#: The protocol's metrics (``abrdf_jax.metrics.evaluate`` keys) and their labels, in print order.
METRICS = {"de76": "dE76", "de2000": "dE2000", "rmse8": "RMSE8", "psnr": "PSNR", "logerr": "LogErr"}

#: What each preset is, for ``--help`` and the model record (``abrdf_jax.preset(NAME, budget)``).
PRESET_HELP = {
    "recommended": "thin-plate spline on the log of the samples, chosen on the MERL train split",
    "paper": "Filip 2012 as published: Gaussian kernel on linear values",
    "operator": "recommended with the linear 'average' rule for axial slices: one matrix product",
}
check_registry("PRESETS", PRESET_HELP)


def preset_help(default: str | None) -> str:
    """The ``--preset`` help text, the same in every command."""
    kinds = "; ".join(f"{name}: {text}" for name, text in PRESET_HELP.items())
    return (
        "named configuration abrdf_jax.preset(NAME, budget), the same in reconstruct, fit and "
        f"btf reconstruct ({kinds})" + (f"; default {default}" if default else "")
    )


def version() -> str:
    try:
        from importlib.metadata import version as installed

        return installed("abrdf_jax")
    except Exception:  # noqa: BLE001 - not installed: the source tree's version
        from .. import __version__

        return __version__


def verbose_parent() -> argparse.ArgumentParser:
    """A parent parser with ``-v``; its default is suppressed so a later level cannot reset it."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=argparse.SUPPRESS,
        help="show a traceback on error",
    )
    return p


def command(sub, name: str, func, help: str, description: str | None = None, writes=False):
    """Add subcommand ``name`` (with ``-v``) to ``sub``, run by ``func(args)`` (``None``: a group);
    a command that ``writes`` quotes the overwrite policy at the end of its ``--help``."""
    epilog = OVERWRITE_POLICY if writes else None
    p = sub.add_parser(
        name, parents=[verbose_parent()], help=help, description=description, epilog=epilog
    )
    if func is not None:
        p.set_defaults(func=func)
    return p


def adder(p, helps: dict):
    """``p.add_argument`` whose ``help`` defaults to ``helps[the option's last name]``: each
    command keeps its help texts in one table and each option on one line."""

    def add(*names, **kw):
        return p.add_argument(*names, **{"help": helps.get(names[-1]), **kw})

    return add


def budget_flags(p, anisotropic: bool = True) -> None:
    """``--isotropic`` (and ``--anisotropic``): force the budget instead of reading it off the data."""
    g = p.add_mutually_exclusive_group() if anisotropic else p
    g.add_argument("--isotropic", action="store_true", help="use only the diagonal slices (iso102)")
    if anisotropic:
        g.add_argument("--anisotropic", action="store_true", help="use all 8 slices (aniso204)")


def say(message: str) -> None:
    """``abrdf-jax: MESSAGE`` on stderr."""
    print(f"{PROG}: {message}", file=sys.stderr)


def warn(message: str) -> None:
    say(f"warning: {message}")


# --------------------------------------------------------------------------------------------
# Outputs and inputs
# --------------------------------------------------------------------------------------------


def output_lock(out: Path, also=(), announce=True):
    """The writer's lock of an output (:func:`abrdf_jax.cli._outputs.output_lock`), warning here."""
    return _output_lock(out, warn, also, announce)


def expand_inputs(inputs: list[str]) -> tuple[list[Path], bool]:
    """Measurement files named on the command line; a folder contributes its ``*.csv`` files.

    Returns the files and whether the output is a folder (several inputs or a folder input).
    """
    from .._names import MEASUREMENT_SUFFIXES

    files: list[Path] = []
    folder_mode = len(inputs) > 1
    for name in inputs:
        p = Path(name)
        if p.is_dir():
            folder_mode = True
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in MEASUREMENT_SUFFIXES)
            found = [q for q in found if q.is_file()]
            if not found:
                kinds = "/".join(MEASUREMENT_SUFFIXES)
                raise InputError(f"{p}: folder holds no {kinds} measurement files")
            files.extend(found)
        else:
            if not p.exists():
                raise InputError(f"{p}: file not found")
            files.append(p)
    return files, folder_mode


def forced_budget(args) -> str | None:
    """The budget of ``--isotropic``/``--anisotropic`` (``None`` when neither is given)."""
    return "iso102" if args.isotropic else "aniso204" if args.anisotropic else None


class Measured(NamedTuple):
    """One input file on its way to the output: read once, grouped into slices once."""

    path: Path
    samples: object  # the file's columns (numpy, as abrdf_jax.Samples), negative values kept
    meas: object  # the slices (numpy, as abrdf_jax.Measurements), passed on to every later step
    budget: str
    alpha: float  # slice offset, degrees
    used: dict  # what of the file was used (the model record's "measurement" entry)


#: The least a capture must hold to be reconstructed: this many elevation pairs, each with this
#: many samples on its diagonal slice (a slice is interpolated over 360 degrees of azimuth).
#: A pair with fewer diagonal samples is left out (with a warning), not refused.
MIN_PAIRS, MIN_DIAGONAL = 2, 3
#: Warn when less than this fraction of a capture's samples could be used.
MIN_USED_FRACTION = 0.5


def _used(meas, report: dict, n_total: int, weak: list) -> dict:
    """What of a capture is used: pairs, samples per slice, α, what was left out and why."""
    counts = [int(c) for c in report["counts"]]
    raw = [int(c) for c in report["n_raw"]]
    return {
        "alpha_deg": report["alpha_deg"],
        "alpha_se_deg": report["alpha_se_deg"],
        "tolerance_deg": report["tol_deg"],
        "offset_sigma_deg": report["offset_sigma_deg"],
        "pairs": [list(p) for p in meas.pairs],
        "samples_per_slice": [
            {"axial": a, "diagonal": d, "axial_knots": ka, "diagonal_knots": kd}
            for a, d, ka, kd in zip(raw[0::2], raw[1::2], counts[0::2], counts[1::2])
        ],
        "n_samples": n_total,
        "n_used": report["n_used"],
        "n_off_slice": report["n_off_slice"],
        "n_stray": report["n_stray"],
        "dropped_pairs": [list(p) for p in report["dropped_pairs"]],
        "weak_pairs": [list(p) for p in weak],
        "gaps": [dict(g, pair=list(g["pair"])) for g in report["gaps"]],
    }


def _support(meas, report: dict, where: Path):
    """Leave out pairs too thin to interpolate; refuse a capture too small to reconstruct."""
    counts = report["counts"]
    keep = [k for k in range(len(meas.pairs)) if counts[2 * k + 1] >= MIN_DIAGONAL]
    weak = [meas.pairs[k] for k in range(len(meas.pairs)) if k not in keep]
    if len(keep) < MIN_PAIRS:
        why = f"{len(keep)} elevation pair(s) with {MIN_DIAGONAL} or more diagonal samples"
        if weak:
            why += f" (too few at {[list(p) for p in weak]})"
        raise InputError(
            f"{where}: cannot reconstruct from {report['n_used']} usable sample(s): {why}; a "
            f"capture needs at least {MIN_PAIRS} elevation pairs with {MIN_DIAGONAL} or more "
            "samples on each diagonal slice"
        )
    if weak:
        meas = meas.select_slices(keep)
        report = dict(report)  # the left-out pairs' samples count as used no more
        for k in sorted(set(range(len(counts) // 2)) - set(keep)):
            report["n_used"] -= report["n_raw"][2 * k] + report["n_raw"][2 * k + 1]
        report["counts"] = [counts[r] for k in keep for r in (2 * k, 2 * k + 1)]
        report["n_raw"] = [report["n_raw"][r] for k in keep for r in (2 * k, 2 * k + 1)]
    return meas, report, weak


def _warn_used(used: dict, where: Path) -> None:
    """Say on the console what of a capture was left out (the model record says it too)."""
    if used["dropped_pairs"]:
        warn(
            f"{where}: no sample at elevation pair(s) {used['dropped_pairs']}: left out, the RBF "
            f"fills them from the {len(used['pairs'])} measured pair(s)"
        )
    if used["weak_pairs"]:
        warn(
            f"{where}: fewer than {MIN_DIAGONAL} diagonal samples at elevation pair(s) "
            f"{used['weak_pairs']}: left out, the RBF fills them from the other pairs"
        )
    left = used["n_samples"] - used["n_used"]
    if used["n_off_slice"]:
        stray = f", {used['n_stray']} of them at no elevation pair" if used["n_stray"] else ""
        warn(
            f"{where}: {used['n_off_slice']} of {used['n_samples']} samples lie on no slice (more "
            f"than {used['tolerance_deg']:.2g} deg off, alpha {used['alpha_deg']:g} deg{stray}): "
            "left out"
        )
    if left > (1 - MIN_USED_FRACTION) * used["n_samples"]:
        warn(f"{where}: only {used['n_used']} of {used['n_samples']} samples could be used")
    for g in used["gaps"]:
        warn(
            f"{where}: the {g['slice']} slice of pair {g['pair']} has no sample from "
            f"{g['start_deg']:.1f} to {g['end_deg']:.1f} deg: interpolated across the gap"
        )


def fill_noise(items: list["Measured"]) -> None:
    """Set each input's ``noise_log``: the capture's value noise (log units, per slice knot:
    after bin means) from the slices' neighbour residuals
    (:func:`abrdf_jax.select.estimate_noise` over all slices; the files of one layout in one
    pass); an upper bound where a sparse slice's own curvature dominates its residuals."""
    from ..select._isotropy import estimate_noise_many

    for item, sigma in zip(items, estimate_noise_many([it.meas for it in items], slices="all")):
        item.used["noise_log"] = round(sigma, 6) if math.isfinite(sigma) else None


def smoothing_records(items: list["Measured"], configs: list) -> list[dict | None]:
    """The model record's ``smoothing`` entry of every input (``None``: no slice smoothing):
    :func:`abrdf_jax._smoothing.slice_smoothings` (numpy, no JAX; one pass per layout). The
    prior's models have no slice smoothing (they read the samples as they are)."""
    from .._config import Config
    from .._smoothing import slice_smoothings

    ks = [k for k, c in enumerate(configs) if isinstance(c, Config)]
    out = [None] * len(items)
    found = slice_smoothings([items[k].meas for k in ks], [configs[k] for k in ks])
    for k, r in zip(ks, found):
        out[k] = r
    return out


def plan(samples, forced, alpha, where: Path, warn: bool = True, noise: bool = True) -> Measured:
    """Group one measurement into slices (once, numpy: no JAX) and decide its budget and slice
    offset α; ``warn``: say what of it is left out; ``noise=False``: leave ``noise_log`` to a
    :func:`fill_noise` of many inputs at once."""
    from .._grouping import group_arrays

    try:
        meas, report = group_arrays(samples, None if alpha is None else float(alpha))
    except InputError as e:
        raise InputError(f"{where}: {e}") from e
    meas, report, weak = _support(meas, report, where)
    if forced == "aniso204" and not meas.has_axial:
        raise InputError(f"{where}: --anisotropic needs axial slices, but the file has none")
    used = _used(meas, report, len(samples), weak)
    used["noise_log"] = None
    if warn:
        _warn_used(used, where)
    budget = forced or ("aniso204" if meas.has_axial else "iso102")
    item = Measured(where, samples, meas, budget, report["alpha_deg"], used)
    if noise:
        fill_noise([item])
    return item


#: A folder run holds the inputs of at most this many files (~20 KiB each) at once: a larger
#: folder is checked whole, then read again block by block (docs/stability.md, "Load").
BLOCK = 1024


def read_inputs(files, forced, alpha, before=None, quiet=True, keep=True, warn=True):
    """Read, then plan every input (numpy: no JAX; ``before()`` runs in between); one bad file
    fails the run before any work, naming them all. ``keep=False``: check, keep nothing;
    ``warn=False``: no warning (:func:`input_blocks`'s passes). A large folder is read by
    forked reader processes, with the same outcome in file order (:mod:`._readers`)."""
    from . import _readers

    def make_bar():
        return progress(len(files), "read", quiet or len(files) < 2, _progress.READ_BAR_DELAY)

    work = functools.partial(_readers.read_one, plan, warn_values, forced, alpha, keep, warn)
    n, done = _readers.reader_count(files), None
    if n > 1:
        done = _readers.read_parallel(work, files, n, make_bar)
        if done is None:
            say("warning: a reader process ended unexpectedly; reading in this process")
    if done is None:
        done = _readers.read_serial(work, files, quiet, make_bar)
    bad, items = _readers.merged(files, done, keep, before)
    if bad:
        others = ", ".join(str(f) for f, _ in bad[1:4]) + (", ..." if len(bad) > 4 else "")
        more = f" (also bad: {others}; nothing was written)" if len(bad) > 1 else ""
        raise InputError(bad[0][1] + more)
    fill_noise(items)
    for item in items if warn else ():
        warn_values(item.path, item.samples)
    return items


def input_blocks(files, targets, forced, alpha, before, quiet, places=None):
    """``(items, targets)`` of at most :data:`BLOCK` files each, in order; every input is read
    and checked first (above ``BLOCK`` files the blocks are read again: bounded memory).
    ``places``: each file's place in the whole job (a ``--resume`` run reads fewer files): a
    block holds the files of one ``place // BLOCK``, so that a resumed run batches every file
    as the uninterrupted run did (the same bits)."""
    places = list(range(len(files))) if places is None else list(places)
    ids = [p // BLOCK for p in places]
    cuts = [0] + [i for i in range(1, len(ids)) if ids[i] != ids[i - 1]] + [len(ids)]
    if len(cuts) == 2:
        return [(read_inputs(files, forced, alpha, before, quiet), targets)]
    read_inputs(files, forced, alpha, before, quiet, keep=False)
    return (
        (read_inputs(files[a:b], forced, alpha, warn=False), targets[a:b])
        for a, b in zip(cuts[:-1], cuts[1:])
    )


def measurements_for(item: Measured, config):
    """``item``'s slices for ``config``: the grouping made once, unless the configuration names
    elevation pairs other than those it was grouped on (a hand-made parameter file)."""
    from .._grouping import group_arrays
    from .._protocol import PROTOCOL_PAIRS

    if getattr(config, "operator_only", False):  # a learned model reads the slices as grouped
        return item.meas
    pairs = tuple(tuple(float(x) for x in p) for p in config.pairs)
    if pairs in (tuple(item.meas.pairs), tuple(PROTOCOL_PAIRS)):
        return item.meas
    return group_arrays(item.samples, item.alpha, pairs=config.pairs)[0]


def check_params_file(path) -> None:
    """A bad parameter file (``--params``) fails here, before any input is read (no JAX)."""
    if path is not None:
        from ..io._paramfile import read_params_file

        read_params_file(path)


def params_for(budget: str, alpha: float, preset: str = "recommended", params_file=None):
    """Config and params: from a fitted parameter file (``--params``) or ``abrdf_jax.preset``.

    A parameter file supplies the configuration, widths and λ; α (``alpha``, degrees) stays the
    measurement's own (it says where the samples lie), and the file's budget must match the
    data's.
    """
    import abrdf_jax as aj

    if params_file is not None:
        from ..io._paramfile import load_params

        config, params, _ = load_params(params_file)
        if config.budget != budget:
            flag = "isotropic" if config.budget == "iso102" else "anisotropic"
            raise InputError(
                f"{params_file}: parameters were fitted for {config.budget}, but the "
                f"measurement is {budget}; fit for {budget} or pass --{flag}"
            )
        return config, params.with_alpha_deg(alpha)
    config = aj.preset(preset, budget)
    return config, aj.Params.default(config, alpha_deg=alpha)


# --------------------------------------------------------------------------------------------
# Warnings
# --------------------------------------------------------------------------------------------


def warn_values(path: Path, samples) -> None:
    """Warn of what a capture's values hold that its reconstruction cannot show
    (:func:`abrdf_jax.cli._capture_values.value_warnings`)."""
    for message in value_warnings(path, samples):
        warn(message)


def warn_guard(path: Path, meas, config, params, params_file) -> None:
    """Say when the RBF system was ill-conditioned and its regularisation raised (docs/stability.md).

    Only parameters from a file can trigger it: the presets' systems are fixed (protocol pairs,
    tuned widths and λ) and well conditioned in float32 (tests/test_stability.py), so the extra
    compile is skipped for them.
    """
    if params_file is None:
        return
    import abrdf_jax as aj
    from .._engine import as_jax

    meas, params = as_jax(meas, params)
    info = aj.solve_info(meas, config, params)
    if int(info.retries) or not bool(info.ok):
        state = "raised" if bool(info.ok) else "raised, still ill-conditioned"
        warn(
            f"{path}: the RBF system is singular to working precision at the requested "
            f"regularisation; regularisation {state} to {float(info.reg):.3g} (condition "
            f"~{float(info.cond):.2g})"
        )


# The model record (``OUT.model.json``): its own module, used through this one
from ._record import (  # noqa: E402, F401
    MODEL_FORMAT,
    compact,
    describe,
    model_choice,
    save_model_record,
    summary,
)

# The prior-only model (``--model prior``, ``--prior``): its own module, used through this one
from ._learned import (  # noqa: E402, F401
    FUSED_MODEL,
    LEARNED_MODELS,
    PRIOR_MODEL,
    bivariate_choice,
    learned_choice,
    check_prior_arguments,
    prior_choice,
    prior_source,
)

# The caches of a run (``--cache-dir``): their own module, used through this one
from ._caches import CACHE_DIR_HELP, Caches, compilation_cache  # noqa: E402, F401
from ._resume import kept_batches, resumable, settings_key  # noqa: E402, F401

# A folder block's settings and plans (reconstruct DIR): its own module, used through this one
from ._block_plan import block_jobs, lone_of  # noqa: E402, F401

# ``--uncertainty``: its own module, used through this one
from ._uncertainty import HELP as UNCERTAINTY_HELP  # noqa: E402, F401
from ._uncertainty import check_uncertainty, std_path, write_std  # noqa: E402, F401
