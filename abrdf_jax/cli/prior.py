"""``abrdf-jax prior``: train a learned prior from dense tables, show a prior file, export the
default prior.

- ``abrdf-jax prior train TABLES... -o PRIOR.npz [--components K] [--lam L]``: tables (``.npz``/
  ``.exr``, stacks such as the merl-nbrdf ``tables81.npz`` with ``--split train``, MERL
  ``.binary`` files); K and λ not given are chosen by cross-validation within the tables.
- ``abrdf-jax prior info PRIOR.npz [--json]``: format, layout, K, λ, ε, what it was trained on
  (numpy only, no JAX).
- ``abrdf-jax prior default -o PRIOR.npz``: write the default prior (trained on the package's
  analytic materials; docs/prior.md).
"""

from __future__ import annotations

import json
from pathlib import Path

from .._names import BUDGETS, PRIOR_CHANNELS, PRIOR_INPUT_SUFFIXES
from . import _common as common

HELP = {
    "prior": "train, inspect or export a learned prior (PCA of dense tables)",
    "description": "A learned prior of ABRDF tables (Nielsen et al. 2015 style: log-relative "
    "map against the median, scaled principal components, ridge projection of the samples); "
    "see docs/prior.md.",
    "train": "train a prior from dense tables",
    "info": "show what a prior file holds and what it was trained on",
    "default": "write the default prior (trained on the package's analytic materials)",
    "tables": f"training tables: {', '.join(PRIOR_INPUT_SUFFIXES)} files (an .npz may hold a "
    "stack 'abrdf' (N, 81, 81, 3) with 'names' and 'split')",
    "--output": "the prior file to write (.npz)",
    "--components": "number of principal components K (default: chosen by cross-validation)",
    "--lam": "ridge lambda (default: chosen by cross-validation)",
    "--channels": "'shared' (one basis for R, G, B; default) or 'joint' (RGB vectors)",
    "--eps": "epsilon of the log-relative map (default 1e-6)",
    "--split": "keep only the stack entries whose 'split' is this (e.g. train)",
    "--folds": "cross-validation folds (default 6)",
    "--budget": "sample budget of the held-out reconstructions (default iso102)",
    "prior_file": "a prior file (.npz)",
    "--json": "print the summary as JSON",
    "--quiet": "no progress lines",
}


def _train(args) -> int:
    out = common.check_output_file(Path(args.output), (".npz",), "prior file")
    from ..prior import DEFAULT_EPS, read_training_tables, select_prior, train_prior
    from ..prior._select import DEFAULT_KS, DEFAULT_LAMS

    eps = DEFAULT_EPS if args.eps is None else args.eps
    tables, names, sources = read_training_tables(args.tables, split=args.split)
    if not args.quiet:
        common.say(f"read {len(names)} training tables")
    kw = dict(channels=args.channels, eps=eps, sources=sources)
    if args.components is not None and args.lam is not None:
        prior = train_prior(tables, names, k=args.components, lam=args.lam, **kw)
    else:
        log = None if args.quiet else common.say
        ks = DEFAULT_KS if args.components is None else (args.components,)
        lams = DEFAULT_LAMS if args.lam is None else (args.lam,)
        prior = select_prior(
            tables,
            names,
            ks=ks,
            lams=lams,
            channels=(args.channels,),
            eps_values=(eps,),
            folds=args.folds,
            budget=args.budget,
            sources=sources,
            log=log,
        )
    from ..prior import save_prior

    with common.output_lock(out):  # one writer; a killed one's temporary file goes
        save_prior(prior, out)
    sel = prior.metadata.get("selection")
    cv = f", cross-validated dE76 {sel['cv_de76']:.3f}" if sel else ""
    print(f"{out}: K={prior.n_components}, lambda={float(prior.lam):g}{cv}, {len(names)} tables")
    return 0


def _info(args) -> int:
    from ..prior import prior_info

    info = prior_info(args.prior_file)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True))
        return 0
    print(f"{info['file']}: {info['format']}")
    print(
        f"  channels {info['channels']}, K={info['n_components']}, lambda={info['lam']:g}, "
        f"eps={info['eps']:g}, {info['dtype']}"
    )
    print(f"  package version {info.get('package_version')}")
    if "selection" in info:
        s = info["selection"]
        print(f"  chosen by {s.get('by')}: cv dE76 {s.get('cv_de76', float('nan')):.3f}")
    if "provenance" in info:
        print(f"  provenance: {info['provenance']}")
    trained = info["trained_on"]
    print(f"  trained on {len(trained)} tables:")
    for t in trained[:10]:
        print(f"    {t.get('name')}  sha256 {str(t.get('sha256'))[:16]}  {t.get('source', '')}")
    if len(trained) > 10:
        print(f"    ... and {len(trained) - 10} more (--json lists all)")
    return 0


def _default(args) -> int:
    out = common.check_output_file(Path(args.output), (".npz",), "prior file")
    from ..prior import default_prior, save_prior

    prior = default_prior()
    with common.output_lock(out):  # one writer; a killed one's temporary file goes
        save_prior(prior, out)
    print(f"{out}: default prior, K={prior.n_components}, lambda={float(prior.lam):g}")
    return 0


def register(sub) -> None:
    g = common.command(sub, "prior", None, HELP["prior"], HELP["description"])
    gsub = g.add_subparsers(dest="prior_command", metavar="ACTION", required=True)

    t = common.command(gsub, "train", _train, HELP["train"], writes=True)
    add = common.adder(t, HELP)
    add("tables", nargs="+", type=common.existing("file"), metavar="TABLES")
    add("-o", "--output", required=True, metavar="PRIOR.npz")
    add("--components", type=common.positive("--components"), metavar="K")
    add("--lam", type=common.finite("--lam", 0.0, open_low=False), metavar="L")
    add("--channels", choices=PRIOR_CHANNELS, default="shared")
    add("--eps", type=common.finite("--eps", 0.0))
    add("--split", metavar="NAME")
    add("--folds", type=common.integer("--folds", 2), default=6)
    add("--budget", choices=BUDGETS, default=BUDGETS[0])
    add("-q", "--quiet", action="store_true")

    i = common.command(gsub, "info", _info, HELP["info"])
    add = common.adder(i, HELP)
    add("prior_file", metavar="PRIOR.npz")
    add("--json", action="store_true")

    d = common.command(gsub, "default", _default, HELP["default"], writes=True)
    add = common.adder(d, HELP)
    add("-o", "--output", required=True, metavar="PRIOR.npz")


def run(args) -> int:
    return args.func(args)
