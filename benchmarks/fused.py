"""The fused model (prior + stationary kernel on the residual, :mod:`abrdf_jax.prior`) against the
prior-only and the RBF-only models, and the calibration of its predictive variance.

Run: ``python -m benchmarks.fused [--quick]`` → ``results/fused.json`` and ``results/fused.md``
(``fused_quick.*``; ``--quick``: fewer population and evidence steps).

1. **Priors**: the MERL-train prior (K = 32, λ = 0.03: the held-out choice of
   ``python -m benchmarks.prior``, results/prior.md), and for the held-out family a prior trained
   on the train split without that family (names containing ``paint``: 12 materials).
2. **Hyper-parameters**: a population fit by gradient descent on the 6-fold held-out ΔE76
   within each training set (``abrdf_jax.prior.fit_population``, exact iso102 samples), and per
   material by evidence (``fit_evidence``, started at and pulled towards the population fit).
3. **Figures** (exact slice samples, PROTOCOL.md): MERL test iso102 and aniso204, the 8 built-in
   analytic materials at aniso204 (the MERL-train prior), the held-out family at iso102. Methods:
   prior only (``reconstruct_prior``), fused (population), fused (evidence), RBF only
   (``Config.recommended`` of the budget, the float32 pipeline). Per method: mean ΔE76, LogErr,
   the worst per-material ratio of ΔE76 to RBF-only and how many materials are > 3 % worse.
4. **Calibration** (MERL test iso102 and the analytic set): the fraction of the dense truth inside
   the predicted ±1σ / ±2σ multiplicative bands (ideal 68.3 % / 95.4 %). The population fit
   sees the mean only, which depends on the ratios of the scales; its variance is scaled to each
   material's own samples (``fused_rescaled``, the maximum-evidence amplitude).

jaxlib 0.10.2's CPU runtime deadlocked on these programs while the fused model vmapped its
Cholesky solves (LAPACK's batched triangular solve waiting on a busy thread pool; the package now
maps over a stack with ``lax.map``). Turning the concurrency-optimised scheduler off had avoided
it; this module still sets ``--xla_cpu_enable_concurrency_optimized_scheduler=false`` before JAX
starts as a guard (not re-measured without it).
"""

from __future__ import annotations

import os

_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"
if _FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import abrdf_jax as aj  # noqa: E402
from abrdf_jax import prior as P  # noqa: E402

from ._common import RESULTS, machine, mean_metrics, merl_split, metrics_of, sample_batch  # noqa: E402
from ._common import load_average, write_json  # noqa: E402

K, LAM = 32, 0.03
FAMILY = "paint"
START = dict(widths=(0.1, 1.0, 0.5, 1.0), sigma_p=1.0, sigma_k=0.1, sigma_n=0.17)
STEPS = {"quick": dict(population=12, evidence=30), "full": dict(population=60, evidence=80)}


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


@eqx.filter_jit
def _prior_only(meas, prior):
    return P.reconstruct_prior(meas, prior)


@eqx.filter_jit
def _fused(meas, prior, hyper):
    return P.reconstruct_fused(meas, prior, hyper, return_variance=True)


@eqx.filter_jit
def _rescaled(meas, prior, hyper):
    return P.fused_rescaled(meas, prior, hyper)


@eqx.filter_jit
def _evidence_fit(meas, prior, hyper, steps):
    return P.fit_evidence(meas, prior, hyper, steps=steps, lr=0.05, tau=1.0)


def _rbf(meas, budget):
    cfg = aj.Config.recommended(budget)
    return aj.reconstruct_batch(meas, cfg, aj.Params.default(cfg))


def _analytic(budget):
    mats = aj.materials.default_materials()
    cfg = aj.Config(budget=budget)
    p = aj.Params.default(cfg)
    meas = aj.stack_measurements(
        [aj.sample(m, cfg, p, as_measurements=True) for m in mats.values()]
    )
    return (
        list(mats),
        meas,
        jnp.asarray(np.stack([aj.materials.dense_table(m) for m in mats.values()])),
    )


def _population(tables, meas, steps, what):
    t = time.perf_counter()
    h0 = P.FusedHyper.create(**START)
    hyper, losses = P.fit_population(tables, meas, h0, steps=steps, lr=0.1, k=K, log=_log)
    _log(
        f"{what}: population fit {losses[0]:.3f} -> {min(losses):.3f} ({time.perf_counter() - t:.0f} s)"
    )
    return hyper, dict(losses=losses, hyper=hyper.as_dict(), seconds=time.perf_counter() - t)


def _evaluate(name, meas, ref, budget, prior, pop, steps, calibrate):
    """Every method on one dataset: metrics, per-material ΔE76, ratios to RBF-only, coverage."""
    t = time.perf_counter()
    hyp = _evidence_fit(meas, prior, pop, steps)
    fit_s = time.perf_counter() - t
    recs = {
        "prior only": (_prior_only(meas, prior), None),
        "fused (population)": _fused(meas, prior, _rescaled(meas, prior, pop)),
        "fused (evidence)": _fused(meas, prior, hyp),
        "RBF only": (_rbf(meas, budget), None),
    }
    out = {}
    for method, (rec, var) in recs.items():
        per = metrics_of(rec, ref)
        row = dict(mean_metrics(per), de76_per_material=[float(v) for v in per["de76"]])
        if var is not None and calibrate:
            for k in (1.0, 2.0):
                cov = np.asarray(P.fused_coverage(prior, rec, var, ref, k))
                row[f"coverage_{k:g}sigma"] = float(cov.mean())
        out[method] = row
    rbf = np.asarray(out["RBF only"]["de76_per_material"])
    for row in out.values():
        ratio = np.asarray(row["de76_per_material"]) / rbf
        row["worst_ratio_to_rbf"] = float(ratio.max())
        row["n_worse_3pct"] = int(np.sum(ratio > 1.03))
    hyp_med = {
        k: float(np.exp(np.median(np.asarray(v), 0)).mean())
        for k, v in (
            ("sigma_p", hyp.log_sigma_p),
            ("sigma_k", hyp.log_sigma_k),
            ("sigma_n", hyp.log_sigma_n),
        )
    }
    for method, row in out.items():
        extra = "".join(f"  cov{k[9:]} {v:.3f}" for k, v in row.items() if k.startswith("coverage"))
        _log(
            f"{name:34s} {method:20s} dE76 {row['de76']:6.2f}  LogErr {row['logerr']:.3f}  "
            f"worst/RBF {row['worst_ratio_to_rbf']:.2f}{extra}"
        )
    return dict(methods=out, evidence_seconds=fit_s, evidence_median=hyp_med, n=int(len(rbf)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer population and evidence steps")
    args = ap.parse_args(argv)
    steps = STEPS["quick" if args.quick else "full"]
    t0 = time.time()
    tr_names, tr_models, tr_ref, _ = merl_split("train")
    _, te_models, te_ref, _ = merl_split("test")
    iso = aj.Config(budget="iso102")
    tr_meas = sample_batch(tr_models, iso)
    tr_tables = np.asarray(tr_ref)
    prior = P.train_prior(tr_tables, tr_names, k=K, lam=LAM)
    pop, pop_info = _population(tr_tables, tr_meas, steps["population"], "MERL train")

    fam = np.asarray([FAMILY in n for n in tr_names])
    rest_prior = P.train_prior(tr_tables[~fam], k=K, lam=LAM)
    rest_meas = jax.tree_util.tree_map(lambda x: x[~fam], tr_meas)
    rest_pop, rest_info = _population(
        tr_tables[~fam], rest_meas, steps["population"], "train-family"
    )
    fam_meas = jax.tree_util.tree_map(lambda x: x[fam], tr_meas)

    datasets = {
        "merl-test iso102": (sample_batch(te_models, iso), te_ref, "iso102", prior, pop, True),
        "merl-test aniso204": (
            sample_batch(te_models, aj.Config(budget="aniso204")),
            te_ref,
            "aniso204",
            prior,
            pop,
            False,
        ),
        "analytic (built-in 8) aniso204": (
            *_analytic("aniso204")[1:],
            "aniso204",
            prior,
            pop,
            True,
        ),
        f"held-out family '{FAMILY}' iso102": (
            fam_meas,
            jnp.asarray(tr_tables[fam]),
            "iso102",
            rest_prior,
            rest_pop,
            True,
        ),
    }
    results = {}
    for name, (meas, ref, budget, pr, hy, cal) in datasets.items():
        results[name] = _evaluate(name, meas, ref, budget, pr, hy, steps["evidence"], cal)
    out = dict(
        machine=machine(),
        load_average=load_average(),
        quick=args.quick,
        steps=steps,
        prior=dict(
            k=K, lam=LAM, family=FAMILY, family_names=[n for n, f in zip(tr_names, fam) if f]
        ),
        population=pop_info,
        population_without_family=rest_info,
        results=results,
        seconds=time.time() - t0,
    )
    stem = "fused_quick" if args.quick else "fused"
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(_table(out))
    return 0


def _table(out) -> str:
    q = " --quick" if out["quick"] else ""
    h = out["population"]["hyper"]
    lines = [
        f"# The fused model (`python -m benchmarks.fused{q}`)",
        "",
        f"MERL-train prior K={out['prior']['k']}, λ={out['prior']['lam']:g}; population fit "
        f"({out['steps']['population']} steps, 6-fold held-out ΔE76 on MERL train "
        f"{out['population']['losses'][0]:.2f} → {min(out['population']['losses']):.2f}): "
        + ", ".join(f"{k} {v:.3g}" for k, v in h.items() if isinstance(v, float))
        + f"; evidence: {out['steps']['evidence']} Adam steps per material. "
        f"Load {out['load_average']}, {out['seconds']:.0f} s in all.",
        "",
        "| dataset | method | ΔE76 | LogErr | worst ratio to RBF | > 3 % worse | in ±1σ | in ±2σ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for ds, res in out["results"].items():
        for name, r in res["methods"].items():
            c1, c2 = (
                f"{r[k]:.1%}" if k in r else "" for k in ("coverage_1sigma", "coverage_2sigma")
            )
            lines.append(
                f"| {ds} ({res['n']}) | {name} | {r['de76']:.2f} | {r['logerr']:.3f} | "
                f"{r['worst_ratio_to_rbf']:.2f} | {r['n_worse_3pct']} | {c1} | {c2} |"
            )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
