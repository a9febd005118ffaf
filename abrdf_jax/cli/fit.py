"""``abrdf-jax fit``: tune kernel widths, λ (and α) and save them as a parameter JSON file.

- ``abrdf-jax fit self MEAS.csv -o PARAMS.json``: self-calibration of one material from its own
  measurements (leave-one-elevation-pair-out by default; no ground truth needed).
- ``abrdf-jax fit population -o PARAMS.json [--materials merl-train|NAME,NAME,...]``: population
  tuning over training materials with dense references (the MERL train split's neural fits, or
  built-in materials' dense tables), α included unless ``--fixed-alpha``.

The file is read back by ``abrdf-jax reconstruct --params PARAMS.json``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from .._errors import InputError
from .._names import BUDGETS, FOLD_KINDS, LOSSES, PRESETS, SOLVERS, WIDTH_MODES, check_registry
from . import _common as common

#: What each solver is (``abrdf_jax.tuning.fit(solver=...)``), for ``--help``.
SOLVER_HELP = {
    "lm": "optimistix Levenberg-Marquardt",
    "gn": "optimistix Gauss-Newton",
    "bfgs": "optimistix BFGS",
    "lbfgs": "jaxopt L-BFGS",
    "lbfgsb": "jaxopt L-BFGS-B, bounded",
}
check_registry("SOLVERS", SOLVER_HELP)
DEFAULT_PRESET = "recommended"
#: The ``--help`` texts: each command's and each option's.
HELP = {
    "fit": "tune widths, regularisation and alpha; write PARAMS.json",
    "description": "Tune the continuous parameters by gradient-based fitting and save them for "
    "'abrdf-jax reconstruct --params'. A fit that does not converge writes nothing (exit 2); a "
    "doubtful one (parameters at a bound, a loss that rose: then the starting parameters are "
    "kept, a singular system at the result) is written with its warnings printed and kept in "
    "the file ('fit' -> 'warnings').",
    "self": "self-calibration from one measurement CSV",
    "population": "population tuning on training materials",
    "--solver": ", ".join(f"{k} ({v})" for k, v in SOLVER_HELP.items()) + f"; default {SOLVERS[0]}",
    "--steps": "solver iterations (default 20)",
    "--preset": "the configuration to tune: a " + common.preset_help(DEFAULT_PRESET),
    "--widths": "free widths: one per onion coordinate (per_dim, default), one shared, or none "
    "free (fixed)",
    "--fixed-reg": "keep the regularisation at its default",
    "--quiet": "no progress lines; the fit is then compiled without its progress hook, so JAX's "
    "compilation cache keeps it and a rerun does not compile it again",
    "--folds": "leave one elevation pair out (default) or every 4th sample of each slice",
    "--materials": "'merl-train' (MERL train split, needs the data folder) or NAME,NAME,... "
    "(built-in materials; see 'abrdf-jax materials')",
    "--limit": "use at most N materials (evenly spread)",
    "--fixed-alpha": "do not tune alpha",
    "--loss": "residuals: CIELAB differences (sum of squares = sum of dE76^2, default), log, or "
    "both",
    "--cache-dir": common.CACHE_DIR_HELP,
    "--data": "data folder (default: $ABRDF_DATA or ../shared/data)",
}


def _fit_and_save(
    args, out: Path, config, problem, data, params, meta: dict, extra="", meas=None
) -> int:
    """Run the solver; when it converged, save the parameter file (with ``meta``) and say so.

    A doubtful result (parameters at a bound, a loss that rose, and with ``meas`` a singular
    RBF system at the result) is still written, with the warnings inside the file (``fit``,
    ``warnings``) and on the console: the policy ``abrdf-jax fit --help`` states.
    """
    import abrdf_jax as aj
    from .. import tuning

    # -q: no progress hook, so the compiled fit has no host callback and JAX's compilation cache
    # stores it (a rerun loads it); with progress lines every run compiles the fit again
    opts = dict(solver=args.solver, max_steps=args.steps, progress=None if args.quiet else True)
    res = tuning.fit(problem, data, params, **opts)
    if not res.ok:
        raise InputError(f"fit {res.status}: {res.message}; nothing written to {out}")
    if meas is not None:
        info = aj.solve_info(meas, config, res.params)
        if int(info.retries) or not bool(info.ok):
            res.warnings.append(
                "the RBF system at the fitted parameters is singular to working precision: "
                f"reconstructing raises the regularisation to {float(info.reg):.3g}"
            )
    for w in res.warnings:
        common.warn(f"{out}: {w}")
    meta |= {"date": time.strftime("%Y-%m-%d %H:%M:%S"), "version": aj.__version__}
    with common.output_lock(out):  # one writer; a killed one's temporary file goes
        tuning.save_params(out, config, res.params, fit=meta | res.summary())
    p = res.params
    print(
        f"{out}: {res.solver} {res.status} after {res.steps} steps ({res.seconds:.1f} s, compile "
        f"{res.compile_seconds:.1f} s); loss {res.loss_initial:.5g} -> {res.loss_final:.5g}; "
        f"alpha {p.alpha_deg:.2f} deg, widths {', '.join(f'{float(w):.3g}' for w in p.widths)}, "
        f"reg {float(p.reg):.3g}{extra}"
    )
    return 0


def cmd_fit_self(args) -> int:
    import abrdf_jax as aj
    from .. import io

    out = common.check_json_output(Path(args.output))
    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: file not found")
    item = common.plan(io.read_samples_csv(src), common.forced_budget(args), args.alpha, src)
    # JAX's compilation cache: a rerun (the same fit again, or after an interruption) loads what
    # this one compiles instead of compiling for seconds
    common.compilation_cache(args.cache_dir, common.warn)
    from .. import tuning  # imports JAX: only once the input is known good

    config = aj.preset(args.preset, item.budget)
    params = aj.Params.default(config, alpha_deg=item.alpha)
    space = tuning.ParamSpace(widths=args.widths, reg=not args.fixed_reg)
    try:
        calibration = tuning.SelfCalibration.from_samples
        meas = item.meas.to_measurements()  # the planned numpy slices, as the pytree
        prob, data, params = calibration(meas, config, params, space=space, folds=args.folds)
    except InputError as e:
        raise InputError(f"{src}: {e}") from e
    meta = {"mode": "self", "input": str(src), "folds": args.folds, "preset": args.preset}
    return _fit_and_save(
        args, out, config, prob, data, params, meta, f" (held-out log error of {src.name})", meas
    )


def _population_data(names: str, dtype, data_dir):
    """``(source models, reference tables, material names)`` of ``--materials``."""
    import jax.numpy as jnp
    import numpy as np

    from .. import materials

    if names == "merl-train":
        t = materials.load_tables81(data_dir)
        idx = np.nonzero(t["split"] == "train")[0]
        mats = [str(n) for n in t["names"][idx]]
        models = materials.stack_nbrdf(materials.load_nbrdf_all(mats, data_dir))
        return models, jnp.asarray(t["abrdf"][idx], dtype), mats
    mats = [n.strip() for n in names.split(",") if n.strip()]
    if not mats:
        raise InputError(
            "--materials: give 'merl-train' or a comma-separated list of material names"
        )
    tables = []
    for n in mats:
        try:
            m = materials.get_material(n, data_dir)
        except (KeyError, InputError) as e:
            raise InputError(f"--materials: unknown material {n!r} ({e})") from None
        tables.append(materials.dense_table(m, np.float64))
    ref = jnp.asarray(np.stack(tables), dtype)
    return ref, ref, mats


def cmd_fit_population(args) -> int:
    out = common.check_json_output(Path(args.output))
    common.compilation_cache(args.cache_dir, common.warn)  # as in cmd_fit_self
    import jax
    import jax.numpy as jnp

    import abrdf_jax as aj
    from .. import tuning

    config = aj.preset(args.preset, args.budget)
    alpha = args.alpha if args.alpha is not None else 15.0
    params = aj.Params.default(config, alpha_deg=alpha, dtype=jnp.float32)
    source, ref, mats = _population_data(args.materials, params.alpha.dtype, args.data)
    if args.limit:
        n = len(mats)
        sel = jnp.linspace(0, n - 1, min(args.limit, n)).round().astype(int)

        def pick(x):  # the per-material leaves of the source models
            return x[sel] if hasattr(x, "shape") and x.ndim and x.shape[0] == n else x

        source, ref, mats = (
            jax.tree_util.tree_map(pick, source),
            ref[sel],
            [mats[int(i)] for i in sel],
        )
    space = tuning.ParamSpace(
        widths=args.widths, reg=not args.fixed_reg, alpha=not args.fixed_alpha
    )
    prob = tuning.Population(config=config, space=space, loss_kind=args.loss)
    data = tuning.Population.make_data(source, ref, params)
    print(
        f"fitting on {len(mats)} materials ({config.budget}, {args.preset}, {args.solver}, up to "
        f"{args.steps} steps)",
        file=sys.stderr,
    )
    meta = {"mode": "population", "materials": mats, "preset": args.preset, "loss": args.loss}
    return _fit_and_save(args, out, config, prob, data, params, meta)


def register(sub) -> None:
    f = common.command(sub, "fit", None, HELP["fit"], HELP["description"])
    fsub = f.add_subparsers(dest="mode", metavar="MODE", required=True)

    def shared(p):
        add = common.adder(p, HELP)
        add("-o", "--output", required=True, metavar="PARAMS.json")
        add("--solver", choices=SOLVERS, default=SOLVERS[0])
        add("--steps", type=common.positive("--steps"), default=20)
        add("--preset", choices=PRESETS, default=DEFAULT_PRESET)
        add("--widths", choices=WIDTH_MODES, default=WIDTH_MODES[0])
        add("--fixed-reg", action="store_true")
        add("-q", "--quiet", action="store_true")
        add("--cache-dir", metavar="DIR")
        return add

    s = common.command(fsub, "self", cmd_fit_self, HELP["self"], writes=True)
    s.add_argument("input", metavar="MEAS.csv")
    add = shared(s)
    common.budget_flags(s)
    add(
        "--alpha",
        type=common.alpha_deg,
        metavar="DEG",
        help="slice offset (default: read off the data)",
    )
    add("--folds", choices=FOLD_KINDS, default=FOLD_KINDS[0])

    p = common.command(fsub, "population", cmd_fit_population, HELP["population"], writes=True)
    add = shared(p)
    add("--materials", default="merl-train")
    add("--limit", type=common.positive("--limit"))
    add("--budget", choices=BUDGETS, default="iso102")
    add("--alpha", type=common.alpha_deg, metavar="DEG", help="starting slice offset (default 15)")
    add("--fixed-alpha", action="store_true")
    add("--loss", choices=LOSSES, default=LOSSES[0])
    add("--data", type=common.existing("folder"), metavar="DIR")
