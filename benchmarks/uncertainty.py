"""Calibration of the learned models' predictive standard deviation (``reconstruct
--uncertainty``, :func:`abrdf_jax.prior.reconstruct_with_std`) on held-out materials.

Run: ``python -m benchmarks.uncertainty [--quick]`` → ``results/uncertainty{_quick}.json``,
``.md`` and ``.png``.

What the command line computes, on materials no part of it was fitted to: the default prior
(trained on analytic draws; the fused hyper-parameters chosen on MERL *train*), the MERL test
split (54 materials, exact slice samples, PROTOCOL.md; iso102, and without ``--quick`` also
aniso204 and the 8 built-in analytic materials at aniso204), float64, the variance scaled to
each material's samples (maximum evidence), as ``--uncertainty`` writes it. Per model (fused,
prior only): the fraction of the dense truth's values (81 × 81 pairs × RGB) inside the ``±kσ``
multiplicative band (:func:`abrdf_jax.prior.fused_coverage`) for k from 0 to 3, against a
Gaussian's ``2Φ(k) − 1`` (68.3 % at 1σ, 95.4 % at 2σ). Nothing is tuned here.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import abrdf_jax as aj  # noqa: E402
from abrdf_jax import prior as P  # noqa: E402

from ._common import (  # noqa: E402
    RESULTS,
    load_average,
    machine,
    merl_split,
    metrics_of,
    sample_batch,
    write_json,
)

KS = tuple(np.round(np.arange(0, 3.01, 0.25), 2))


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def gaussian(k: float) -> float:
    """``P(|z| ≤ k)`` of a standard normal ``z``."""
    return math.erf(k / math.sqrt(2))


def coverage_rows(prior, meas, truth, alpha=None) -> dict:
    """Per model: the coverage curve (mean over materials), per-material 1σ/2σ, mean std, ΔE76."""
    out = {}
    truth = jnp.asarray(truth, jnp.float64)
    for model in P.VARIANCE_MODELS:
        t = time.perf_counter()
        table, std = P.reconstruct_with_std(meas, prior, model, alpha)
        var = std**2
        per_k = {k: np.asarray(P.fused_coverage(prior, table, var, truth, k)) for k in KS}
        out[model] = {
            "coverage": {str(k): float(np.mean(v)) for k, v in per_k.items()},
            "per_material_1sigma": [float(v) for v in per_k[1.0]],
            "per_material_2sigma": [float(v) for v in per_k[2.0]],
            "mean_std": float(jnp.mean(std)),
            "de76": float(np.mean(metrics_of(np.asarray(table), np.asarray(truth))["de76"])),
            "seconds": time.perf_counter() - t,
        }
        c = out[model]["coverage"]
        _log(f"  {model:6s} 1σ {c['1.0']:.3f} 2σ {c['2.0']:.3f} ΔE76 {out[model]['de76']:.2f}")
    return out


def _analytic():
    mats = aj.materials.default_materials()
    cfg = aj.Config(budget="aniso204")
    p = aj.Params.default(cfg, dtype=jnp.float64)
    meas = aj.stack_measurements(
        [aj.sample(m, cfg, p, as_measurements=True) for m in mats.values()]
    )
    return meas, np.stack([aj.materials.dense_table(m) for m in mats.values()])


def chart(out: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = list(out["datasets"])
    fig, axes = plt.subplots(1, len(sets), figsize=(4.2 * len(sets), 4), squeeze=False)
    ks = np.asarray(KS, float)
    for ax, name in zip(axes[0], sets):
        ax.plot(ks, [gaussian(k) for k in ks], "k--", label="Gaussian 2Φ(k)−1")
        for model, rows in out["datasets"][name].items():
            ax.plot(ks, [rows["coverage"][str(k)] for k in KS], "o-", ms=3, label=model)
        ax.axhline(0.683, color="grey", lw=0.5)
        ax.axhline(0.954, color="grey", lw=0.5)
        ax.set_xlabel("k (band ±kσ, multiplicative)")
        ax.set_ylabel("fraction of the dense truth inside")
        ax.set_ylim(0, 1)
        ax.set_title(name, fontsize=9)
        ax.legend(fontsize=8)
    fig.suptitle(
        f"python -m benchmarks.uncertainty{' --quick' if out['quick'] else ''}", fontsize=9
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(out: dict) -> str:
    q = " --quick" if out["quick"] else ""
    lines = [
        f"# Calibration of the predictive std (`python -m benchmarks.uncertainty{q}`)",
        "",
        f"{out['date']}, load {out['load_average']}, {out['seconds']:.0f} s. Default prior, "
        "float64, variance scaled to each material's samples. Fraction of the dense truth inside "
        "±1σ / ±2σ (Gaussian: 68.3 % / 95.4 %); per material: the lowest and highest.",
        "",
        "| dataset | model | ±1σ | ±2σ | ±3σ | per material ±2σ (min–max) | mean σ | ΔE76 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in out["datasets"].items():
        for model, r in rows.items():
            c, p2 = r["coverage"], r["per_material_2sigma"]
            lines.append(
                f"| {name} | {model} | {100 * c['1.0']:.1f} % | {100 * c['2.0']:.1f} % | "
                f"{100 * c['3.0']:.1f} % | {100 * min(p2):.0f}–{100 * max(p2):.0f} % | "
                f"{r['mean_std']:.3f} | {r['de76']:.2f} |"
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="MERL test iso102 only")
    args = ap.parse_args(argv)
    t0 = time.time()
    prior = P.default_prior().astype(jnp.float64)
    _, models, ref, _ = merl_split("test")
    budgets = ("iso102",) if args.quick else ("iso102", "aniso204")
    datasets = {}
    for budget in budgets:
        _log(f"MERL test {budget}")
        cfg = aj.Config(budget=budget)
        meas = sample_batch(models, cfg, aj.Params.default(cfg, dtype=jnp.float64))
        datasets[f"MERL test {budget} (54)"] = coverage_rows(prior, meas, ref)
    if not args.quick:
        _log("analytic aniso204")
        datasets["analytic aniso204 (8)"] = coverage_rows(prior, *_analytic())
    out = dict(machine(), quick=args.quick, datasets=datasets)
    out |= dict(load_average=load_average(), seconds=time.time() - t0)
    stem = "uncertainty_quick" if args.quick else "uncertainty"
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(markdown(out))
    chart(out, RESULTS / f"{stem}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
