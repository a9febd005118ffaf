"""How the spike cap was chosen: ``Config.spike_cap`` on the MERL train split, five capture kinds.

Run: ``python -m benchmarks.spike_cap [--quick]``. Writes ``benchmarks/results/spike_cap.json``
and ``spike_cap.md`` (``--quick``: ``spike_cap_quick.*``: every third material, three settings;
``--report``: only the markdown again, from the stored JSON).

For each material of the MERL *train* split (merl-nbrdf fits; the test split is never looked
at here) five iso102 captures are simulated with :func:`abrdf_jax.simulate_capture` (seed
``SEED + i`` of ``benchmarks.captures``, whose kinds these are): the protocol capture, 100 samples per slice, 0.5°
angle jitter, 5 % value noise and the protocol plus the pairs 45/45 and 60/60. Each is grouped
(:func:`abrdf_jax.group_slices`) and reconstructed with the recommended configuration and
``spike_cap=(quantile, margin)`` (or ``None``: no cap), and ΔE76 is taken against the dense
truth. The default (``Config.spike_cap``) was the setting with the lowest mean ΔE76 over the
five kinds; the table gives every kind's mean and its ratio to the protocol capture's. Where a
rerun finds another setting lowest, the report adds the paired difference of the two over the
materials (mean ± standard error): the default changes only for a difference larger than twice
its standard error, since every figure of the package moves with it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics

from ._captures_kinds import KINDS as CAPTURE_KINDS
from ._common import RESULTS, load_average, machine, write_json
from .captures import SEED

SETTINGS = (
    None,
    (0.8, 0.5),
    (0.85, 0.5),
    (0.9, 0.25),
    (0.9, 0.5),
    (0.93, 0.5),
    (0.95, 0.25),
    (0.95, 0.5),
    (0.97, 0.25),
)
QUICK_SETTINGS = (None, (0.93, 0.5), (0.95, 0.5))
#: The five capture kinds, as ``benchmarks.captures`` defines them (``simulate_capture`` keywords).
KINDS = {
    k: CAPTURE_KINDS[k].capture
    for k in ("protocol", "dense-100", "jitter-0.5", "noise-5", "extra-pairs")
}


def captures(names):
    """``{name: (dense truth, {kind: (Measurements, report)})}``."""
    out = {}
    for i, n in enumerate(names):
        model = materials.get_material("nbrdf:" + n)
        ref = np.asarray(materials.dense_table("nbrdf:" + n), np.float32)
        out[n] = (
            ref,
            {
                k: aj.group_slices(aj.simulate_capture(model, budget="iso102", seed=SEED + i, **kw))
                for k, kw in KINDS.items()
            },
        )
    return out


def run_setting(caps, cap) -> dict:
    """Per-kind ΔE76 lists of one ``spike_cap`` setting."""
    cfg = aj.preset("recommended", "iso102", spike_cap=cap)
    res = {k: [] for k in KINDS}
    for ref, kinds in caps.values():
        for k, (meas, rep) in kinds.items():
            params = aj.Params.default(cfg, alpha_deg=rep["alpha_deg"])
            table = np.asarray(aj.reconstruct(meas, cfg, params), np.float32)
            res[k].append(float(metrics.evaluate(table, ref)["de76"]))
    return res


def markdown(rows, payload) -> str:
    kinds = list(KINDS)
    lines = [
        "# The spike cap, chosen on the MERL train split",
        "",
        f"`{payload['command']}`; {payload['n_materials']} train materials, iso102, the "
        "recommended configuration with `spike_cap=(quantile, margin)`. Mean ΔE76 per capture "
        "kind (ratio to the protocol capture's); the last column the mean over the five kinds. "
        f"Load average before/after: {payload['load_before']} / {payload['load_after']}; "
        f"{payload['seconds']:.0f} s.",
        "",
        "| spike_cap | " + " | ".join(kinds) + " | mean |",
        "|---" * (len(kinds) + 2) + "|",
    ]
    default = str(aj.Config().spike_cap)
    for r in rows:
        base = r["mean"]["protocol"]
        cells = [f"{r['mean'][k]:.3f} ({r['mean'][k] / base:.2f}x)" for k in kinds]
        mark = " **lowest**" if r["setting"] == payload["chosen"] else ""
        mark += " (the default)" if r["setting"] == default else ""
        lines.append(f"| {r['setting']}{mark} | " + " | ".join(cells) + f" | {r['overall']:.3f} |")
    if payload["chosen"] != default:
        by = {r["setting"]: r for r in rows}
        d = paired(by[default], by[payload["chosen"]])
        lines += [
            "",
            f"The lowest mean is not the default's: {payload['chosen']} against {default} "
            "(`Config.spike_cap`). Paired over the materials (each material's mean over the "
            f"kinds): the default is higher by {d['mean']:.4f} ± {d['se']:.4f} (mean ± standard "
            f"error), lower on {d['lower']} of {d['n']} materials. The default is kept unless "
            "the difference exceeds twice its standard error (docs/captures.md, step 7).",
        ]
    return "\n".join(lines) + "\n"


def paired(a: dict, b: dict) -> dict:
    """Row ``a`` against row ``b``: the mean and standard error of each material's difference
    of its mean ΔE76 over the kinds (``a − b``), and on how many materials ``a`` is lower."""
    kinds = list(a["per_material"])
    diff = np.mean([np.subtract(a["per_material"][k], b["per_material"][k]) for k in kinds], 0)
    n = len(diff)
    se = float(np.std(diff, ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    return {"mean": float(np.mean(diff)), "se": se, "lower": int(np.sum(diff < 0)), "n": n}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.spike_cap", description=__doc__)
    ap.add_argument("--quick", action="store_true", help="every third material, three settings")
    ap.add_argument(
        "--report", action="store_true", help="rewrite the markdown from the stored JSON only"
    )
    args = ap.parse_args(argv)
    stem = "spike_cap_quick" if args.quick else "spike_cap"
    if args.report:
        import json

        payload = json.loads((RESULTS / f"{stem}.json").read_text())
        (RESULTS / f"{stem}.md").write_text(markdown(payload["rows"], payload))
        return payload
    t0, load0 = time.perf_counter(), load_average()
    names = materials.merl_split("train")[:: 3 if args.quick else 1]
    caps = captures(names)
    rows = []
    for cap in QUICK_SETTINGS if args.quick else SETTINGS:
        res = run_setting(caps, cap)
        mean = {k: float(np.mean(v)) for k, v in res.items()}
        rows.append(
            {
                "setting": str(cap),
                "spike_cap": cap,
                "mean": mean,
                "per_material": res,
                "overall": float(np.mean(list(mean.values()))),
            }
        )
        print(f"spike_cap={cap}: " + " ".join(f"{k} {v:.3f}" for k, v in mean.items()), flush=True)
    best = min(rows, key=lambda r: r["overall"])
    payload = {
        "command": "python -m benchmarks.spike_cap" + (" --quick" if args.quick else ""),
        "machine": machine(),
        "materials": list(names),
        "n_materials": len(names),
        "kinds": KINDS,
        "rows": rows,
        "chosen": best["setting"],
        "load_before": load0,
        "load_after": load_average(),
        "seconds": time.perf_counter() - t0,
    }
    write_json(f"{stem}.json", payload)
    (RESULTS / f"{stem}.md").write_text(markdown(rows, payload))
    print(f"chosen: spike_cap={best['setting']} (mean ΔE76 over the kinds {best['overall']:.3f})")
    return payload


if __name__ == "__main__":
    main()
