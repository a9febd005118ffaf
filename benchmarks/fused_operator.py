"""The fused model as the command line runs it (issue 14, "Operator and batch", "Model choice").

Run: ``python -m benchmarks.fused_operator [--quick]`` → ``results/fused_operator{_quick}.json``
and ``.md``.

1. **Accuracy of ``--model fused``** on the MERL test split: the numpy operators the command line
   applies (``abrdf_jax.compile_numpy_operator``: one entry per layout, here one layout for the
   whole split, exact slice samples, PROTOCOL.md) of the default prior alone, of the fused model
   at the default prior's fixed hyper-parameters (chosen on MERL train only,
   ``benchmarks.fused_defaults``), and of the RBF (``preset("operator")``, what
   ``--preset operator`` runs). iso102 and aniso204 (``--quick``: iso102 only). **Where the mean
   lies**: the test materials whose reference table is exactly 0 over more than 1 % of its values
   (the neural fits' final clamp, ../shared/data/merl-nbrdf/SOURCE.md "Trust"), each model's
   ΔE76 on them and its mean over the others, and its mean with the reference's zeros imposed
   on its table (an oracle, not a model: what knowing the clamped regions would be worth).
2. **The automatic choice on the built-in analytic materials** (anisotropic and non-reciprocal
   among them; ``--quick``: 3 of them), exact aniso204 samples: ``select_model`` without a prior
   (the RBF pick), and with the default prior (the prior and the fused model join); the full-table
   ΔE76 of the RBF pick, the prior alone, the fused model and of what the choice with the prior
   picked. A database model picked where the kernel is better is counted.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import prior as P
from abrdf_jax import select

from ._common import (
    RESULTS,
    load_average,
    machine,
    merl_split,
    metric_cells,
    metrics_of,
    sample_batch,
    write_json,
)

QUICK_MATERIALS = ("ggx-aniso-metal", "rough-fabric", "ggx-plastic")


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def _de76(rec, ref) -> np.ndarray:
    return np.asarray(metrics_of(np.asarray(rec), np.asarray(ref))["de76"])


def merl_accuracy(prior, budgets) -> tuple[dict, dict]:
    """Mean ΔE76 and LogErr of the three numpy operators on the MERL test split, per budget, and
    each material's fraction of exact zeros in its reference table."""
    names, models, ref, _ = merl_split("test")
    ref_np = np.asarray(ref)
    zeros = (ref_np == 0).mean(axis=(1, 2, 3))  # the fits' exact-zero regions (SOURCE.md)
    out = {}
    for budget in budgets:
        cfg = aj.Config(budget=budget)
        meas = sample_batch(models, cfg)
        one = _first(meas)
        params = aj.Params.default(aj.preset("operator", budget))
        ops = {
            "RBF operator (preset operator)": aj.compile_numpy_operator(
                aj.preset("operator", budget), one, params
            ),
            "prior only (default prior)": aj.compile_numpy_operator(prior, one, budget=budget),
            "fused (default prior)": aj.compile_numpy_operator(
                prior, one, budget=budget, fused=True
            ),
        }
        y = np.asarray(meas.y, np.float32)
        rows = {}
        for name, op in ops.items():
            rec = np.asarray(op.apply(y))
            per = metrics_of(rec, ref)
            rows[name] = {k: float(np.mean(v)) for k, v in per.items()}
            rows[name]["de76_per_material"] = [float(v) for v in per["de76"]]
            # an oracle, not a model: the reference's exact zeros imposed on the reconstruction
            oracle = metrics_of(np.where(ref_np == 0, 0.0, rec), ref)["de76"]
            rows[name]["de76_zeros_imposed"] = float(np.mean(oracle))
            _log(f"MERL test {budget} {name:32s} dE76 {rows[name]['de76']:.3f}")
        out[budget] = rows
    return out, {"materials": names, "zero_fraction": [float(z) for z in zeros]}


def _first(meas):
    import jax

    return jax.tree_util.tree_map(lambda x: x[0], meas)


def analytic_choice(prior, names) -> list[dict]:
    """The choice with and without the prior on each material, and the full-table errors."""
    mats = aj.materials.default_materials()
    cfg = aj.Config(budget="aniso204")
    rows = []
    for name in names:
        t = time.perf_counter()
        meas = aj.sample(mats[name], cfg, aj.Params.default(cfg), as_measurements=True)
        truth = np.asarray(aj.materials.dense_table(mats[name]))[None]
        rbf_sel = select.select_model(meas)
        sel = select.select_model(meas, prior=prior)
        budget = "aniso204" if rbf_sel.config.budget == "aniso204" else "iso102"
        rec = {
            "rbf": rbf_sel.reconstruct(meas),  # its model (the bivariate one, an RBF config)
            "prior": aj.compile_numpy_operator(prior, meas, budget=budget).apply(meas.y),
            "fused": aj.compile_numpy_operator(prior, meas, budget=budget, fused=True).apply(
                meas.y
            ),
        }
        de = {k: float(_de76(np.asarray(v)[None], truth)[0]) for k, v in rec.items()}
        pick = sel.name if sel.name in ("prior", "fused") else "rbf"
        row = {
            "material": name,
            "rbf_pick": rbf_sel.name,
            "pick": sel.name,
            "held_out": {k: float(v) for k, v in sel.errors.items()},
            "de76": de,
            "de76_pick": de[pick],
            "database_pick_worse_than_kernel": pick != "rbf" and de[pick] > de["rbf"],
            "seconds": time.perf_counter() - t,
        }
        _log(
            f"{name:20s} pick {sel.name:15s} dE76 rbf({rbf_sel.name}) {de['rbf']:.2f} prior "
            f"{de['prior']:.2f} fused {de['fused']:.2f}  ({row['seconds']:.0f} s)"
        )
        rows.append(row)
    return rows


def _held(errors: dict, name: str) -> str:
    """A held-out error, or "–" for a model that has none (the bivariate one)."""
    return f"{errors[name]:.3f}" if name in errors else "–"


def _zero_lines(merl: dict, zero: dict | None) -> list[str]:
    """Where the MERL test mean lies: the materials whose reference is exactly 0 over large
    regions (../shared/data/merl-nbrdf/SOURCE.md, "Trust": the networks' final clamp; real MERL
    values there are small but positive), the mean without them, and with the reference's zeros
    imposed (an oracle)."""
    if not zero:
        return []
    names, zeros = zero["materials"], np.asarray(zero["zero_fraction"])
    clamped = zeros > 0.01
    lines = [
        "",
        "Where the mean lies: the reference tables of "
        + ", ".join(f"{n} ({z:.0%})" for n, z in zip(names, zeros) if z > 0.01)
        + " are exactly 0 over that fraction of their values (the fits' final clamp, "
        "../shared/data/merl-nbrdf/SOURCE.md: real MERL values there are small but positive).",
        "",
        f"| budget | model | ΔE76 of those {int(clamped.sum())} | mean of the other "
        f"{int((~clamped).sum())} | all, the reference's zeros imposed (oracle) |",
        "|---|---|---|---|---|",
    ]
    for budget, rows in merl.items():
        for name, r in rows.items():
            per = np.asarray(r["de76_per_material"])
            lines.append(
                f"| {budget} | {name} | "
                + ", ".join(f"{v:.2f}" for v in per[clamped])
                + f" | {per[~clamped].mean():.2f} | {r['de76_zeros_imposed']:.2f} |"
            )
    return lines


def _markdown(out) -> str:
    q = " --quick" if out["quick"] else ""
    lines = [
        f"# The fused model on the command line's path (`python -m benchmarks.fused_operator{q}`)",
        "",
        f"Load {out['load_average']}, {out['seconds']:.0f} s. Default prior; fused "
        f"hyper-parameters {out['fused_settings']}.",
        "",
        "## MERL test split, the numpy operators (exact samples)",
        "",
        "| budget | model | ΔE76 | LogErr | ΔE2000 | PSNR |",
        "|---|---|---|---|---|---|",
    ]
    for budget, rows in out["merl_test"].items():
        for name, r in rows.items():
            lines.append(f"| {budget} | {name} | {metric_cells(r)} |")
    lines += _zero_lines(out["merl_test"], out.get("merl_test_zeros"))
    lines += [
        "",
        "## The automatic choice, built-in analytic materials (aniso204, exact samples)",
        "",
        "| material | RBF pick | pick with the prior | held-out: RBF pick / prior / fused | "
        "ΔE76 RBF pick | prior | fused | database model picked where the kernel is better |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in out["analytic"]:
        h = r["held_out"]
        lines.append(
            f"| {r['material']} | {r['rbf_pick']} | {r['pick']} | "
            f"{_held(h, r['rbf_pick'])} / {h['prior']:.3f} / {h['fused']:.3f} | "
            f"{r['de76']['rbf']:.2f} | {r['de76']['prior']:.2f} | {r['de76']['fused']:.2f} | "
            f"{'yes' if r['database_pick_worse_than_kernel'] else 'no'} |"
        )
    rows = out["analytic"]
    mean = {k: np.mean([r["de76"][k] for r in rows]) for k in ("rbf", "prior", "fused")}
    picked = np.mean([r["de76_pick"] for r in rows])
    lines.append(
        f"| mean ({len(rows)}) | | ΔE76 of the pick {picked:.2f} | | {mean['rbf']:.2f} | "
        f"{mean['prior']:.2f} | {mean['fused']:.2f} | "
        f"{sum(r['database_pick_worse_than_kernel'] for r in rows)} |"
    )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="iso102 only, 3 analytic materials")
    ap.add_argument("--skip-merl", action="store_true", help="only the analytic choice")
    args = ap.parse_args(argv)
    t0 = time.time()
    prior = P.default_prior()
    budgets = ("iso102",) if args.quick else ("iso102", "aniso204")
    names = QUICK_MATERIALS if args.quick else tuple(aj.materials.default_materials())
    out = dict(
        machine(),
        quick=args.quick,
        fused_settings={
            k: v for k, v in prior.metadata.get("fused", {}).items() if k != "chosen_on"
        },
    )
    merl, zeros = ({}, None) if args.skip_merl else merl_accuracy(prior, budgets)
    out |= dict(merl_test=merl, merl_test_zeros=zeros, analytic=analytic_choice(prior, names))
    out |= dict(load_average=load_average(), seconds=time.time() - t0)
    stem = "fused_operator_quick" if args.quick else "fused_operator"
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(_markdown(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
