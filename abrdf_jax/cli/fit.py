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
SOLVER_HELP = {"lm": "optimistix Levenberg-Marquardt", "gn": "optimistix Gauss-Newton", "bfgs": "optimistix BFGS",
               "lbfgs": "jaxopt L-BFGS", "lbfgsb": "jaxopt L-BFGS-B, bounded"}
check_registry("SOLVERS", SOLVER_HELP)
DEFAULT_PRESET = "recommended"


def _report(res, out: Path, extra: str = "") -> int:
    if not res.ok:
        raise InputError(f"fit {res.status}: {res.message}; nothing written to {out}")
    p = res.params
    print(f"{out}: {res.solver} {res.status} after {res.steps} steps ({res.seconds:.1f} s, compile "
          f"{res.compile_seconds:.1f} s); loss {res.loss_initial:.5g} -> {res.loss_final:.5g}; "
          f"alpha {p.alpha_deg:.2f} deg, widths {', '.join(f'{float(w):.3g}' for w in p.widths)}, "
          f"reg {float(p.reg):.3g}{extra}")
    return 0


def cmd_fit_self(args) -> int:
    import abrdf_jax as aj
    from .. import io

    out = common.check_json_output(Path(args.output))
    src = Path(args.input)
    if not src.exists():
        raise InputError(f"{src}: file not found")
    item = common.plan(io.read_samples_csv(src), common.forced_budget(args), args.alpha, src)
    from .. import tuning  # imports JAX: only once the input is known good

    config = aj.preset(args.preset, item.budget)
    params = aj.Params.default(config, alpha_deg=item.alpha)
    space = tuning.ParamSpace(widths=args.widths, reg=not args.fixed_reg)
    try:
        prob, data, params = tuning.SelfCalibration.from_samples(item.meas, config, params, space=space,
                                                                 folds=args.folds)
    except InputError as e:
        raise InputError(f"{src}: {e}") from e
    res = tuning.fit(prob, data, params, solver=args.solver, max_steps=args.steps, progress=not args.quiet)
    meta = {"mode": "self", "input": str(src), "folds": args.folds, "preset": args.preset,
            "date": time.strftime("%Y-%m-%d %H:%M:%S"), "version": aj.__version__, **res.summary()}
    if res.ok:
        tuning.save_params(out, config, res.params, fit=meta)
    return _report(res, out, f" (held-out log error of {src.name})")


def _population_data(aj, names: str, config, params, data_dir):
    import jax.numpy as jnp
    import numpy as np

    from .. import materials

    if names == "merl-train":
        t = materials.load_tables81(data_dir)
        idx = np.nonzero(t["split"] == "train")[0]
        mats = [str(n) for n in t["names"][idx]]
        models = materials.stack_nbrdf(materials.load_nbrdf_all(mats, data_dir))
        ref = jnp.asarray(t["abrdf"][idx], params.alpha.dtype)
        return models, ref, mats
    mats = [n.strip() for n in names.split(",") if n.strip()]
    if not mats:
        raise InputError("--materials: give 'merl-train' or a comma-separated list of material names")
    tables = []
    for n in mats:
        try:
            m = materials.get_material(n, data_dir)
        except (KeyError, InputError) as e:
            raise InputError(f"--materials: unknown material {n!r} ({e})") from None
        tables.append(materials.dense_table(m, np.float64))
    ref = jnp.asarray(np.stack(tables), params.alpha.dtype)
    return ref, ref, mats


def cmd_fit_population(args) -> int:
    out = common.check_json_output(Path(args.output))
    import jax
    import jax.numpy as jnp

    import abrdf_jax as aj
    from .. import tuning

    config = aj.preset(args.preset, args.budget)
    params = aj.Params.default(config, alpha_deg=args.alpha if args.alpha is not None else 15.0, dtype=jnp.float32)
    source, ref, mats = _population_data(aj, args.materials, config, params, args.data)
    if args.limit:
        sel = jnp.linspace(0, len(mats) - 1, min(args.limit, len(mats))).round().astype(int)
        source = jax.tree_util.tree_map(
            lambda x: x[sel] if hasattr(x, "shape") and x.ndim and x.shape[0] == len(mats) else x, source)
        ref = ref[sel]
        mats = [mats[int(i)] for i in sel]
    space = tuning.ParamSpace(widths=args.widths, reg=not args.fixed_reg, alpha=not args.fixed_alpha)
    prob = tuning.Population(config=config, space=space, loss_kind=args.loss)
    data = tuning.Population.make_data(source, ref, params)
    print(f"fitting on {len(mats)} materials ({config.budget}, {args.preset}, {args.solver}, "
          f"up to {args.steps} steps)", file=sys.stderr)
    res = tuning.fit(prob, data, params, solver=args.solver, max_steps=args.steps, progress=not args.quiet)
    meta = {"mode": "population", "materials": mats, "preset": args.preset, "loss": args.loss,
            "date": time.strftime("%Y-%m-%d %H:%M:%S"), "version": aj.__version__, **res.summary()}
    if res.ok:
        tuning.save_params(out, config, res.params, fit=meta)
    return _report(res, out)


def register(sub) -> None:
    """Add the ``fit`` subcommand to the ``abrdf-jax`` parser."""
    f = sub.add_parser("fit", parents=[common.verbose_parent()],
                       help="tune widths, regularisation and alpha; write PARAMS.json",
                       description="Tune the continuous parameters by gradient-based fitting and save "
                       "them for 'abrdf-jax reconstruct --params'.")
    fsub = f.add_subparsers(dest="mode", metavar="MODE")
    fsub.required = True

    def shared(p):
        p.add_argument("-o", "--output", required=True, metavar="PARAMS.json")
        p.add_argument("--solver", choices=SOLVERS, default=SOLVERS[0],
                       help=", ".join(f"{k} ({v})" for k, v in SOLVER_HELP.items()) + f"; default {SOLVERS[0]}")
        p.add_argument("--steps", type=int, default=20, help="solver iterations (default 20)")
        p.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET,
                       help="the configuration to tune: a " + common.preset_help(DEFAULT_PRESET))
        p.add_argument("--widths", choices=WIDTH_MODES, default=WIDTH_MODES[0],
                       help="free widths: one per onion coordinate (per_dim, default), one shared, or none (fixed)")
        p.add_argument("--fixed-reg", action="store_true", help="keep the regularisation at its default")
        p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")

    verbose = common.verbose_parent()
    s = fsub.add_parser("self", parents=[verbose], help="self-calibration from one measurement CSV")
    s.add_argument("input", metavar="MEAS.csv")
    shared(s)
    g = s.add_mutually_exclusive_group()
    g.add_argument("--isotropic", action="store_true")
    g.add_argument("--anisotropic", action="store_true")
    s.add_argument("--alpha", type=float, metavar="DEG", help="slice offset (default: read off the data)")
    s.add_argument("--folds", choices=FOLD_KINDS, default=FOLD_KINDS[0],
                   help="leave one elevation pair out (default) or every 4th sample of each slice")
    s.set_defaults(func=cmd_fit_self)

    p = fsub.add_parser("population", parents=[verbose], help="population tuning on training materials")
    shared(p)
    p.add_argument("--materials", default="merl-train",
                   help="'merl-train' (MERL train split, needs the data folder) or NAME,NAME,... "
                        "(built-in materials; see 'abrdf-jax materials')")
    p.add_argument("--limit", type=int, help="use at most N materials (evenly spread)")
    p.add_argument("--budget", choices=BUDGETS, default="iso102")
    p.add_argument("--alpha", type=float, metavar="DEG", help="starting slice offset (default 15)")
    p.add_argument("--fixed-alpha", action="store_true", help="do not tune alpha")
    p.add_argument("--loss", choices=LOSSES, default=LOSSES[0],
                   help="residuals: CIELAB differences (sum of squares = sum of dE76^2, default), log, or both")
    p.add_argument("--data", metavar="DIR", help="data folder (default: $ABRDF_DATA or ../shared/data)")
    p.set_defaults(func=cmd_fit_population)
