"""Noise-driven slice smoothing (``Config.slice_smoothing``): the choice on MERL train, the gain on test.

Run: ``python -m benchmarks.noise_smoothing --split train`` (the choice) then
``python -m benchmarks.noise_smoothing --split test`` (the report); ``--quick``: every ninth
material and fewer settings. Writes ``benchmarks/results/noise_smoothing_{split}.json`` and
``.md`` (``_quick`` added with ``--quick``).

For every ``--every``-th material of the split (merl-nbrdf fits), iso102 captures of two
densities (the protocol's 25/25/26/26 samples per slice and 100 per slice) at relative value
noise 0, 2, 5, 10 and 20 % are simulated with :func:`abrdf_jax.simulate_capture` (seed
``SEED + i`` of ``benchmarks.captures``), grouped, and reconstructed with the recommended
configuration and each ``slice_smoothing`` setting: off (``None``), fixed weights ``β`` and
the noise-driven rule ``(β_max, floor, scale)`` on a small grid (train only). ΔE76 against the
dense truth, mean per cell; beside it the capture's noise estimate
(:func:`abrdf_jax.select.estimate_noise`, log luminance, the model record's ``noise_log``) and the
median weight the rule gave the diagonal slices. On train the rule with the lowest mean ΔE76
over the ten cells is chosen (it must not cost more than 0.5 % on the noise-free captures); on
test the settings compared are off, the fixed weights and the package's default (or, when the
default is off, the rule chosen on train, read from its JSON).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics, select

from ._common import RESULTS, load_average, machine, write_json
from .captures import SEED

NOISE = (0.0, 0.02, 0.05, 0.10, 0.20)
KINDS = {"protocol": {}, "dense-100": {"per_slice": 100}}
FIXED = (0.2, 0.4)
#: The rule's grid on train: β_max = 2/3 (the weight that minimises the variance of pure noise
#: after one shrink), the curvature floor and the signal scale at the protocol's spacing.
RULES = tuple((round(2 / 3, 4), f, s) for f in (0.02, 0.03, 0.045) for s in (0.1, 0.2, 0.4))
QUICK_RULES = ((round(2 / 3, 4), 0.03, 0.2),)
#: How much more the chosen rule may cost than no smoothing on a noise-free capture.
CLEAN_TOLERANCE = 1.005


def captures(names, noise, kw):
    """Stacked grouped measurements of every material at one noise level and density."""
    meas, alphas, sig = [], [], []
    for i, n in enumerate(names):
        model = materials.get_material("nbrdf:" + n)
        s = aj.simulate_capture(model, budget="iso102", seed=SEED + i, noise=noise, **kw)
        m, rep = aj.group_slices(s)
        meas.append(m)
        alphas.append(rep["alpha_deg"])
        sig.append(float(select.estimate_noise(m, slices="all")))
    if np.ptp(alphas) > 1e-6:
        raise RuntimeError(
            f"captures without jitter should share α; got {min(alphas)}–{max(alphas)}"
        )
    return aj.stack_measurements(meas), alphas[0], sig, meas


def run_cell(refs, stacked, alpha, members, settings) -> dict:
    """``{setting: (ΔE76 per material, median diagonal β, σ̂ the rule read per material)}`` of
    one capture kind and noise."""
    out = {}
    for setting in settings:
        cfg = aj.preset("recommended", "iso102", slice_smoothing=setting)
        params = aj.Params.default(cfg, alpha_deg=alpha)
        tables = np.asarray(aj.reconstruct_batch(stacked, cfg, params), np.float32)
        de = [float(metrics.evaluate(t, r)["de76"]) for t, r in zip(tables, refs)]
        reports = [aj.slice_smoothing(m, cfg) for m in members]
        beta = [np.median(r["beta"][1::2]) for r in reports if r is not None]
        sig = [r["noise_log"] for r in reports if r is not None and r["noise_log"] is not None]
        out[str(setting)] = (de, float(np.median(beta)) if beta else 0.0, sig)
    return out


def markdown(payload) -> str:
    cells = payload["cells"]
    settings = payload["settings"]
    lines = [
        f"# Noise-driven slice smoothing, MERL {payload['split']}",
        "",
        f"`{payload['command']}`: {payload['n_materials']} materials (one in "
        f"{payload['every']} of the split), iso102, recommended configuration; mean ΔE76 per "
        "capture (ratio to no smoothing), the noise estimate (median; log luminance, the model "
        "record's `noise_log`), the σ̂ the rule read (median; the reconstruction's log samples) "
        "and the median weight β of the diagonal slices. Load average before/after: "
        f"{payload['load_before']} / {payload['load_after']}; {payload['seconds']:.0f} s.",
        "",
        "| capture | noise | estimate | rule's σ̂ | " + " | ".join(map(str, settings)) + " |",
        "|---" * (len(settings) + 4) + "|",
    ]
    for c in cells:
        off = np.mean(c["de76"]["None"])
        rule = "" if not c.get("rule_noise") else f"{np.median(c['rule_noise']):.4f}"
        row = [c["kind"], f"{100 * c['noise']:g} %", f"{np.median(c['estimate']):.4f}", rule]
        for s in map(str, settings):
            m = np.mean(c["de76"][s])
            beta = "" if s == "None" else f", β {c['beta'][s]:.2f}"
            row.append(f"{m:.3f} ({m / off:.3f}x{beta})")
        lines.append("| " + " | ".join(row) + " |")
    lines.append(
        "| mean | | | | " + " | ".join(f"{payload['overall'][str(s)]:.3f}" for s in settings) + " |"
    )
    if payload.get("chosen") is not None:
        lines += ["", f"Chosen (lowest mean, clean captures within 0.5 %): `{payload['chosen']}`"]
    return "\n".join(lines) + "\n"


def _test_rule(quick: bool):
    """The setting reported on test: the package default, or the rule chosen on train."""
    default = aj.Config.recommended().slice_smoothing
    if default is not None:
        return default
    stem = "noise_smoothing_train" + ("_quick" if quick else "")
    path = RESULTS / f"{stem}.json"
    if not path.exists():
        raise SystemExit(f"run `python -m benchmarks.noise_smoothing --split train` first ({path})")
    return tuple(json.loads(path.read_text())["chosen_setting"])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.noise_smoothing", description=__doc__)
    ap.add_argument("--split", choices=("train", "test"), default="train")
    ap.add_argument("--every", type=int, default=3, help="every k-th material of the split")
    ap.add_argument("--quick", action="store_true", help="every ninth material, fewer settings")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    t0, load0 = time.perf_counter(), load_average()
    every = 9 if args.quick else args.every
    names = materials.merl_split(args.split)[::every]
    if args.split == "train":
        rules = QUICK_RULES if args.quick else RULES
    else:
        rules = (_test_rule(args.quick),)
    settings = [None, *FIXED, *rules]
    refs = [np.asarray(materials.dense_table("nbrdf:" + n), np.float32) for n in names]
    cells = []
    for kind, kw in KINDS.items():
        for noise in NOISE:
            stacked, alpha, sig, members = captures(names, noise, kw)
            res = run_cell(refs, stacked, alpha, members, settings)
            cells.append(
                {
                    "kind": kind,
                    "noise": noise,
                    "estimate": sig,
                    "de76": {k: v[0] for k, v in res.items()},
                    "beta": {k: v[1] for k, v in res.items()},
                    # σ̂ the rule read (the reconstruction's log samples), per material
                    "rule_noise": next((v[2] for v in res.values() if v[2]), None),
                }
            )
            means = " ".join(f"{k}: {np.mean(v[0]):.3f}" for k, v in res.items())
            print(f"{kind} noise {noise:g}: {means} ({time.perf_counter() - t0:.0f} s)", flush=True)
    overall = {
        str(s): float(np.mean([np.mean(c["de76"][str(s)]) for c in cells])) for s in settings
    }
    chosen = None
    if args.split == "train":

        def clean_ok(s):
            return all(
                np.mean(c["de76"][str(s)]) <= CLEAN_TOLERANCE * np.mean(c["de76"]["None"])
                for c in cells
                if c["noise"] == 0
            )

        ok = [r for r in rules if clean_ok(r)]
        chosen = min(ok, key=lambda r: overall[str(r)]) if ok else None
    stem = f"noise_smoothing_{args.split}" + ("_quick" if args.quick else "")
    payload = {
        "command": " ".join(["python -m benchmarks.noise_smoothing", *argv]),
        "machine": machine(),
        "split": args.split,
        "every": every,
        "materials": list(names),
        "n_materials": len(names),
        "settings": [None if s is None else s for s in settings],
        "cells": cells,
        "overall": overall,
        "chosen": None if chosen is None else str(chosen),
        "chosen_setting": chosen,
        "load_before": load0,
        "load_after": load_average(),
        "seconds": time.perf_counter() - t0,
    }
    write_json(f"{stem}.json", payload)
    (RESULTS / f"{stem}.md").write_text(markdown(payload))
    print(markdown(payload))
    return payload


if __name__ == "__main__":
    main()
