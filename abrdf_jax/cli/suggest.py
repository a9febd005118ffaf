"""``abrdf-jax suggest``: where to measure next, from a measurement CSV.

The learned model (``--model fused``, default, or ``prior``) is a Gaussian process whose
posterior variance does not depend on the sample values, so the effect of one more slice is
known before it is measured: every candidate slice (an elevation pair of ``--pairs``, default
the UBO rings, times a kind, axial or diagonal, at the capture's α, ``--samples`` samples) is
scored by the fraction of the total predictive variance over the 81 × 81 output grid it would
remove (:func:`abrdf_jax.prior.suggest_slices`), and the candidates are printed best first
(``--json``: one JSON document). The slices the model already reads are not proposed.
"""

from __future__ import annotations

import json
from pathlib import Path

from .._names import VARIANCE_MODELS
from . import _common as common

HELP = {
    "help": "propose the next slice to measure",
    "description": "Rank candidate slices (elevation pair x axial/diagonal, at the capture's "
    "alpha) by how much of the learned model's total predictive variance over the output grid "
    "their samples would remove, given the measured samples (docs/prior.md, 'Where to measure "
    "next'). Imports JAX.",
    "input": "measurement CSV file",
    "--model": "the learned model whose variance is lowered: fused (default) or prior",
    "--prior": "prior file ('abrdf-jax prior train') or 'default' (the built-in prior)",
    "--pairs": "candidate elevation pairs THETA_I/THETA_V in degrees, comma separated, each in "
    "[0, 90) (default: every pair of the UBO rings 0, 15, ..., 75)",
    "--kinds": "candidate slice kinds, comma separated (default axial,diagonal)",
    "--samples": "samples per candidate slice (default: the most of any measured slice)",
    "--top": "print only the best N candidates (default 10; --json lists all)",
    "--alpha": "slice offset (default: read off the data)",
    "--json": "print one JSON document (every candidate, best first)",
    "--cache-dir": common.CACHE_DIR_HELP,
}


def _kinds(text: str) -> tuple[str, ...]:
    import argparse

    kinds = tuple(k.strip() for k in text.split(","))
    if not kinds or any(k not in ("axial", "diagonal") for k in kinds):
        raise argparse.ArgumentTypeError(f"slice kinds are axial and/or diagonal, got {text!r}")
    return kinds


def register(sub) -> None:
    s = common.command(sub, "suggest", run, HELP["help"], HELP["description"])
    add = common.adder(s, HELP)
    add("input", metavar="MEAS", type=common.existing("file"))
    add("--model", choices=VARIANCE_MODELS, default="fused")
    add("--prior", metavar="FILE")
    common.budget_flags(s)
    add("--alpha", type=common.alpha_deg, metavar="DEG")
    add("--pairs", type=common.elevation_pairs, metavar="TI/TV[,...]")
    add("--kinds", type=_kinds, default=("axial", "diagonal"), metavar="KIND[,KIND]")
    add("--samples", type=common.int_in("--samples", 1, 1000), metavar="N")
    add("--top", type=common.int_in("--top", 1, 10_000), default=10, metavar="N")
    add("--json", action="store_true")
    add("--cache-dir", metavar="DIR")


def run(args) -> int:
    from .. import io
    from .._prior_operator import resolve_prior, slice_counts

    path = Path(args.input)
    item = common.plan(io.read_sample_columns(path), common.forced_budget(args), args.alpha, path)
    source = resolve_prior(args.prior, args.cache_dir)  # a bad prior file fails here
    rows = _rank(item, source, args)
    doc = {
        "input": str(path),
        "model": args.model,
        "budget": item.budget,
        "alpha_deg": float(item.alpha),
        "measured": [
            {"pair": list(p), "axial": int(c[0]), "diagonal": int(c[1])}
            for p, c in zip(item.meas.pairs, slice_counts(item.meas, item.budget).reshape(-1, 2))
        ],
        "prior": source.record(),
        "score": "fraction of the total latent predictive variance over the 81x81 output grid "
        "(all channels) that the slice's samples would remove; exact for the model",
        "candidates": [r | {"pair": list(r["pair"])} for r in rows],
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(
        f"{path}: {item.budget}, alpha {item.alpha:g} deg, --model {args.model}; "
        f"{len(rows)} candidate slices, best first (variance removed: fraction of the total "
        "predictive variance over the output grid)"
    )
    print(f"{'rank':>4}  {'pair':>11}  {'kind':<8}  {'samples':>7}  {'removed':>8}")
    for r in rows[: args.top]:
        pair = f"{r['pair'][0]:g}/{r['pair'][1]:g}"
        print(
            f"{r['rank']:>4}  {pair:>11}  {r['kind']:<8}  {r['samples']:>7}  "
            f"{100 * r['reduction']:>7.2f}%"
        )
    return 0


def _rank(item, source, args) -> list[dict]:
    import numpy as np

    from .._cache import x64_scope
    from .._prior_operator import float64_template, slice_counts
    from ..prior import suggest_slices

    with x64_scope(True):
        import jax.numpy as jnp

        _, meas = float64_template(item.meas, slice_counts(item.meas, item.budget))
        alpha = jnp.asarray(np.deg2rad(item.alpha), jnp.float64)
        prior = source.load().astype(jnp.float64)
        return suggest_slices(
            meas, prior, args.model, alpha, pairs=args.pairs, samples=args.samples, kinds=args.kinds
        )
