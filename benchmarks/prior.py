"""The package's learned priors (:mod:`abrdf_jax.prior`) against each other and the RBF.

Run: ``python -m benchmarks.prior [--quick]`` → ``results/prior.json`` and ``results/prior.md``
(``prior_quick.*``).

1. **The default prior's hyper-parameters**: K by 6-fold cross-validation within its own
   training set (the analytic draws of :data:`abrdf_jax.prior.DEFAULT_RECIPE`, iso102 samples
   interpolated in the log domain from the tables); λ on the MERL train split (exact iso102
   samples; the draws' own cross-validation prefers λ → 0, being noise-free materials of their
   own family). The recipe's K and λ are set from this; a mismatch is reported.
2. **The MERL-train prior**: the same cross-validation on the MERL train split's tables
   (``tables81.npz``), then trained on the whole split (``abrdf_jax.prior.select_prior``,
   exactly what ``abrdf-jax prior train tables81.npz --split train`` does).
3. **Figures** on the MERL test split (exact slice samples of the neural fits, PROTOCOL.md) at
   iso102 and aniso204, and on the 8 built-in analytic materials (exact aniso204 samples): the
   default prior, the MERL-train prior, and the RBF with the recommended settings (the float32
   pipeline, ``Config.recommended`` of the budget). The priors use the package's reconstruction
   (:func:`abrdf_jax.prior.reconstruct_prior`: the prior interpolated at the samples), not the
   PCA peer's basis at the model directions (``benchmarks.pca_peer``, the suite's PCA row).
"""

from __future__ import annotations

import argparse
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax import prior as P

from ._common import (
    RESULTS,
    load_average,
    machine,
    mean_metrics,
    merl_split,
    metric_cells,
    metrics_of,
    sample_batch,
    write_json,
)

GRID = dict(ks=(8, 16, 32, 64, 96, 128), lams=(0.001, 0.003, 0.01, 0.03, 0.1, 0.3))
QUICK_GRID = dict(ks=(32, 64, 96), lams=(0.01, 0.03))


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def _cv(tables, grid, what):
    t = time.perf_counter()
    rows = P.cross_validate_prior(tables, **grid, folds=6)
    best = min(rows, key=lambda r: r["de76"])
    _log(
        f"{what}: cv best K={best['n_components']} lam={best['lam']:g} dE76 {best['de76']:.3f} "
        f"({time.perf_counter() - t:.0f} s)"
    )
    return rows, best


def _analytic_measurements(budget):
    mats = aj.materials.default_materials()
    cfg = aj.Config(budget=budget)
    p = aj.Params.default(cfg)
    meas = aj.stack_measurements(
        [aj.sample(m, cfg, p, as_measurements=True) for m in mats.values()]
    )
    refs = jnp.asarray(np.stack([aj.materials.dense_table(m) for m in mats.values()]))
    return list(mats), meas, refs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small cross-validation grids")
    args = ap.parse_args(argv)
    grid = QUICK_GRID if args.quick else GRID
    t0 = time.time()

    tables_d, names_d = P.default_training_tables()
    rows_d, best_d = _cv(tables_d, grid, "default (analytic draws)")
    recipe = P.DEFAULT_RECIPE
    _, tr_models, tr_ref, _ = merl_split("train")
    tr_meas = sample_batch(tr_models, aj.Config(budget="iso102"))
    draws = P.train_prior(tables_d, names_d, k=best_d["n_components"])
    lam_rows = []
    for lam in grid["lams"]:
        rec = eqx.filter_jit(P.reconstruct_prior)(tr_meas, draws, lam)
        lam_rows.append(dict(lam=lam, **mean_metrics(metrics_of(rec, tr_ref))))
        _log(
            f"default prior K={draws.n_components} on MERL train: lam={lam:g} "
            f"dE76 {lam_rows[-1]['de76']:.3f}"
        )
    lam_best = min(lam_rows, key=lambda r: r["de76"])["lam"]
    recipe_kl = (recipe["k"], recipe["lam"])
    chosen_kl = (best_d["n_components"], lam_best)
    if recipe_kl != chosen_kl:
        _log(f"note: DEFAULT_RECIPE has K, lam = {recipe_kl}, this grid chose {chosen_kl}")
    t = time.perf_counter()
    default = P.default_prior(cache_dir="off")
    build_s = time.perf_counter() - t

    data = aj.materials.load_tables81()
    train = data["split"] == "train"
    rows_m, _ = _cv(data["abrdf"][train], grid, "MERL train")
    merl = P.select_prior(data["abrdf"][train], data["names"][train], **grid, folds=6)

    _, te_models, te_ref, _ = merl_split("test")
    datasets = {}
    for budget in ("iso102", "aniso204"):
        cfg = aj.Config(budget=budget)
        datasets[f"merl-test {budget}"] = (sample_batch(te_models, cfg), te_ref, budget)
    _, a_meas, a_ref = _analytic_measurements("aniso204")
    datasets["analytic (built-in 8) aniso204"] = (a_meas, a_ref, "aniso204")

    rec_prior = eqx.filter_jit(P.reconstruct_prior)
    results = {}
    for ds, (meas, ref, budget) in datasets.items():
        cfg = aj.Config.recommended(budget)
        methods = {
            "default prior": lambda m: rec_prior(m, default),
            "MERL-train prior": lambda m: rec_prior(m, merl),
            "RBF recommended": lambda m, c=cfg: aj.reconstruct_batch(m, c, aj.Params.default(c)),
        }
        results[ds] = {}
        for name, fn in methods.items():
            rec = jax.block_until_ready(fn(meas))
            per = metrics_of(rec, ref)
            results[ds][name] = dict(
                mean_metrics(per), de76_per_material=[float(v) for v in per["de76"]]
            )
            _log(
                f"{ds:32s} {name:18s} dE76 {results[ds][name]['de76']:6.2f}  "
                f"LogErr {results[ds][name]['logerr']:.3f}"
            )

    out = dict(
        machine=machine(),
        load_average=load_average(),
        quick=args.quick,
        grid={k: list(v) for k, v in grid.items()},
        default=dict(
            recipe=recipe,
            cv_best=best_d,
            cv_rows=rows_d,
            lam_on_merl_train=lam_rows,
            build_seconds=build_s,
            n_components=default.n_components,
            lam=float(default.lam),
        ),
        merl_train=dict(
            cv_rows=rows_m,
            n_components=merl.n_components,
            lam=float(merl.lam),
            cv_de76=merl.metadata["selection"]["cv_de76"],
        ),
        results=results,
        seconds=time.time() - t0,
    )
    stem = "prior_quick" if args.quick else "prior"
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(_table(out, stem))
    return 0


def _table(out, stem) -> str:
    d, m = out["default"], out["merl_train"]
    lines = [
        f"# Learned priors (`python -m benchmarks.prior{' --quick' if out['quick'] else ''}`)",
        "",
        f"Default prior: {d['recipe']['n']} analytic draws, K={d['n_components']}, "
        f"λ={d['lam']:g} (K by cv on the draws: K={d['cv_best']['n_components']}, cv ΔE76 "
        f"{d['cv_best']['de76']:.2f}; λ on MERL train: "
        + ", ".join(f"{r['lam']:g} → {r['de76']:.2f}" for r in d["lam_on_merl_train"])
        + f"; built in {d['build_seconds']:.1f} s). "
        f"MERL-train prior: K={m['n_components']}, λ={m['lam']:g} (cv ΔE76 {m['cv_de76']:.2f}).",
        "",
        "| dataset | method | ΔE76 | LogErr | ΔE2000 | PSNR |",
        "|---|---|---|---|---|---|",
    ]
    for ds, rows in out["results"].items():
        for name, r in rows.items():
            lines.append(f"| {ds} | {name} | {metric_cells(r)} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
