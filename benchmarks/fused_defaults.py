"""The fused model's fixed hyper-parameters for the default prior, chosen on the MERL *train*
split only (issue 14, "Operator and batch"): what ``abrdf-jax reconstruct --model fused`` uses.

Run: ``python -m benchmarks.fused_defaults [--steps N] [--from-defaults]`` →
``results/fused_defaults.json``.

The default prior is trained on the package's analytic draws (docs/prior.md), so every MERL train
material is held out from it: the hyper-parameters are fitted by Adam on the mean ΔE76
(PROTOCOL.md) of the fused reconstruction of the 54 MERL train materials from their exact iso102
slice samples, started at the population fit of ``python -m benchmarks.fused --quick`` (itself
fitted within MERL train; ``--from-defaults``: at the current ``FUSED_DEFAULTS``, to continue a
fit), keeping the best step. The prior is ``default_prior()`` as the command line reads it (its
basis at the exact sample directions). The MERL test split is not read. The numbers go
into ``DEFAULT_RECIPE["fused"]`` by hand (a changed recipe is a new default prior key).
"""

from __future__ import annotations

import argparse
import sys
import time

import equinox as eqx
import jax
import numpy as np

import abrdf_jax as aj
from abrdf_jax import prior as P
from abrdf_jax.metrics import delta_e76

from ._common import load_average, machine, merl_split, sample_batch, write_json

#: The start: ``benchmarks.fused --quick``'s population fit on MERL train (docs/prior.md).
START = dict(widths=(0.12, 2.7, 0.34, 0.85), sigma_p=1.0, sigma_k=0.11, sigma_n=0.14)


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=12, help="Adam steps (default 12)")
    ap.add_argument("--lr", type=float, default=0.1)
    ap.add_argument(
        "--from-defaults",
        action="store_true",
        help="start at the current FUSED_DEFAULTS instead of the population fit",
    )
    args = ap.parse_args(argv)
    t0 = time.time()
    # the default prior as the command line reads it: its basis at the exact sample directions
    # (docs/prior.md "The basis at the samples"); its own fused numbers are not read here
    prior = P.default_prior()
    names, models, ref, _ = merl_split("train")
    meas = sample_batch(models, aj.Config(budget="iso102"))
    prior_only = float(
        jax.numpy.mean(jax.vmap(delta_e76)(eqx.filter_jit(P.reconstruct_prior)(meas, prior), ref))
    )
    _log(f"default prior alone, MERL train iso102: dE76 {prior_only:.4f}")
    start = START
    if args.from_defaults:
        d = P.FUSED_DEFAULTS
        start = dict(
            widths=tuple(d["widths"]), **{k: d[k] for k in ("sigma_p", "sigma_k", "sigma_n")}
        )
    init = P.FusedHyper.create(**start)
    hyper, losses = P.fit_population(
        np.asarray(ref), meas, init, steps=args.steps, lr=args.lr, prior=prior, log=_log
    )
    best = min(losses)
    out = dict(
        machine(),
        load_average=load_average(),
        steps=args.steps,
        lr=args.lr,
        start=start,
        prior_only_train_de76=prior_only,
        losses=losses,
        best_train_de76=best,
        hyper=hyper.as_dict(),
        n_train=len(names),
        seconds=time.time() - t0,
    )
    write_json("fused_defaults.json", out)
    _log(f"losses {[round(v, 4) for v in losses]}")
    _log(f"best MERL train dE76 {best:.4f}: {hyper.as_dict()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
