"""The bivariate ``(θh, θd)`` model against the package's RBF on isotropic captures.

Run: ``python -m benchmarks.bivariate [--quick]``. Writes ``benchmarks/results/bivariate.json``,
``bivariate.md`` and the chart ``bivariate.png`` (``_quick`` with ``--quick``).

What is measured (:func:`abrdf_jax.reconstruct_bivariate`; Romeiro et al. 2008, "Passive
reflectometry": isotropic BRDFs are nearly functions of ``(θh, θd)``):

- **settings, on the MERL train split only**: ``log_eps`` × ``smoothing`` on every third train
  material, protocol captures (iso102): the mean ΔE76 of each; and ``pair_width`` (the measured
  pairs' residual curves, :mod:`abrdf_jax._pair_residual`; 0: the spline alone) on the same
  materials, protocol and 100-sample captures; the module's defaults should be (near) the best
  cells.
- **against the RBF**: the MERL train and test splits (merl-nbrdf fits) captured as iso102 by
  :func:`abrdf_jax.simulate_capture` (seed ``12 + i`` per material, as ``benchmarks.captures``)
  in several kinds (the protocol capture, 100 samples a slice, 0.5° jitter, two extra pairs,
  pairs off the UBO rings); the RBF is the command line as a user runs it, one folder call
  per kind (``python -m abrdf_jax.cli reconstruct DIR -o OUT -q --model iso``: the recommended
  RBF, what ``--model auto`` chose for iso102 captures before the bivariate model), the bivariate
  model the library call on the same samples; ΔE76 and LogErr against the dense truth, mean
  and median over materials, the materials where each is better, and the mean of the better of
  the two per material (what a perfect choice between them would reach).
- **where it fails**: the package's analytic materials (``materials.default_materials``,
  anisotropic ones among them), protocol iso102 captures: an anisotropic material is not a
  function of ``(θh, θd)``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import abrdf_jax as aj
from abrdf_jax import io, materials

from ._captures_kinds import KINDS
from ._common import RESULTS, load_average, machine, write_json
from .captures import _file, errors, run_cli, summary

KIND_NAMES = ("protocol", "dense-100", "jitter-0.5", "extra-pairs", "off-ubo")
QUICK_KINDS = ("protocol", "dense-100")
SWEEP = {"log_eps": (1e-2, 1e-3, 1e-4), "smoothing": (1e-5, 1e-3, 1e-1)}
WIDTHS = (0.0, 5.0, 10.0, 15.0, 20.0, 30.0)  # pair_width, degrees
WIDTH_KINDS = ("protocol", "dense-100")
SEED = 12


def _captures(models: dict, kind: str) -> dict:
    kw = KINDS[kind].capture
    return {
        n: aj.simulate_capture(m, budget="iso102", seed=SEED + i, **kw)
        for i, (n, m) in enumerate(models.items())
    }


def _cell(samples: dict, refs: dict, log, **setting) -> dict:
    """One cell of a sweep: ``setting`` (keyword arguments of ``reconstruct_bivariate``) and the
    mean ΔE76 of its tables of ``samples``."""
    de = float(
        np.mean(
            [
                errors(aj.reconstruct_bivariate(s, **setting), refs[n])["de76"]
                for n, s in samples.items()
            ]
        )
    )
    log("  sweep " + " ".join(f"{k} {v:g}" for k, v in setting.items()) + f": mean ΔE76 {de:.3f}")
    return {**setting, "de76": de}


def sweep(models: dict, refs: dict, log) -> list[dict]:
    """Mean ΔE76 of every (log_eps, smoothing) cell on the given (train) materials."""
    samples = _captures(models, "protocol")
    return [
        _cell(samples, refs, log, log_eps=eps, smoothing=lam)
        for eps in SWEEP["log_eps"]
        for lam in SWEEP["smoothing"]
    ]


def width_sweep(models: dict, refs: dict, log) -> list[dict]:
    """Mean ΔE76 of every ``pair_width`` on the given (train) materials, per capture kind."""
    rows = []
    for kind in WIDTH_KINDS:
        samples = _captures(models, kind)
        log(f"  {kind}:")
        rows += [{"kind": kind, **_cell(samples, refs, log, pair_width=w)} for w in WIDTHS]
    return rows


def compare(models: dict, refs: dict, kind: str, work: Path, log) -> dict:
    """The RBF (one CLI folder call) and the bivariate model on one capture kind."""
    samples = _captures(models, kind)
    folder = work / kind
    folder.mkdir(parents=True)
    for n, s in samples.items():
        io.write_samples_csv(folder / f"{n}.csv", s)
    cli = run_cli(folder, work / f"{kind}.out", list(models), ("--model", "iso"))
    tables = cli.pop("tables")
    if not cli["ok"]:
        raise RuntimeError(f"{kind}: the command line failed: {cli['error_lines']}")
    t0 = time.perf_counter()
    biv = {n: aj.reconstruct_bivariate(s) for n, s in samples.items()}
    seconds = (time.perf_counter() - t0) / len(samples)
    rbf = summary({n: errors(tables[n], refs[n]) for n in models})
    bv = summary({n: errors(biv[n], refs[n]) for n in models})
    better = [n for n in models if bv["per_material"][n]["de76"] < rbf["per_material"][n]["de76"]]
    log(
        f"  {kind:12s} RBF ΔE76 {rbf['de76']:.3f} (median {rbf['de76_median']:.3f})  bivariate "
        f"{bv['de76']:.3f} ({bv['de76_median']:.3f}); bivariate better on {len(better)} of "
        f"{len(models)}; {seconds * 1e3:.0f} ms a material"
    )
    return {
        "samples": int(np.median([len(s) for s in samples.values()])),
        "rbf": rbf,
        "bivariate": bv,
        "bivariate_better": better,
        "bivariate_seconds_per_material": seconds,
        "cli_seconds": cli["seconds"],
    }


def run(quick: bool, log) -> dict:
    train = materials.merl_split("train")
    test = materials.merl_split("test")
    if quick:
        train, test = train[::18][:3], test[::18][:3]
    sets = {
        "merl-train": {f"nbrdf:{n}": None for n in train},
        "merl-test": {f"nbrdf:{n}": None for n in test},
        "analytic": {n: None for n in materials.default_materials()},
    }
    out: dict = {"sets": {}}
    with tempfile.TemporaryDirectory(prefix="bivariate-") as tmp:
        for set_name, names in sets.items():
            models = {_file(n): materials.get_material(n) for n in names}
            refs = {n: materials.dense_table(m) for n, m in models.items()}
            log(f"{set_name}: {len(models)} materials")
            block: dict = {"materials": list(models), "kinds": {}}
            if set_name == "merl-train":
                sub = dict(list(models.items())[::3])
                block["sweep"] = sweep(sub, {n: refs[n] for n in sub}, log)
                block["width_sweep"] = width_sweep(sub, {n: refs[n] for n in sub}, log)
            kinds = (
                ("protocol",) if set_name == "analytic" else QUICK_KINDS if quick else KIND_NAMES
            )
            for kind in kinds:
                block["kinds"][kind] = compare(models, refs, kind, Path(tmp) / set_name, log)
            out["sets"][set_name] = block
    return out


def markdown(payload: dict) -> str:
    lines = [
        f"# The bivariate (θh, θd) model against the RBF ({payload['mode']} run)",
        "",
        f"`{payload['command']}`; {payload['machine']['date']}, load {payload['load_before']} → "
        f"{payload['load_after']}, {payload['seconds']:.0f} s. RBF: `python -m abrdf_jax.cli "
        "reconstruct DIR -o OUT -q --model iso` (one folder call per kind; until the bivariate "
        "model became the automatic choice of isotropic materials, `--model auto` chose `iso` for "
        "these captures); bivariate: "
        "`abrdf_jax.reconstruct_bivariate` on the same samples (iso102 captures, seed 12 + i). "
        "ΔE76 / LogErr against the dense truth, mean (median) over materials.",
    ]
    for set_name, block in payload["sets"].items():
        lines += [
            "",
            f"## {set_name} ({len(block['materials'])} materials)",
            "",
            "| capture | samples | RBF ΔE76 | bivariate ΔE76 | RBF LogErr | bivariate LogErr | "
            "bivariate better on | better of the two per material (oracle) ΔE76 | "
            "ms a material (bivariate) |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for kind, r in block["kinds"].items():
            a, b = r["rbf"], r["bivariate"]
            pa, pb = a["per_material"], b["per_material"]
            oracle = np.mean([min(pa[n]["de76"], pb[n]["de76"]) for n in pa])
            lines.append(
                f"| {kind} | {r['samples']} | {a['de76']:.2f} ({a['de76_median']:.2f}) | "
                f"{b['de76']:.2f} ({b['de76_median']:.2f}) | {a['logerr']:.3f} | "
                f"{b['logerr']:.3f} | {len(r['bivariate_better'])} of {len(block['materials'])} | "
                f"{oracle:.2f} | {r['bivariate_seconds_per_material'] * 1e3:.0f} |"
            )
        lines.append("")
        for kind, r in block["kinds"].items():
            worse = [n for n in block["materials"] if n not in r["bivariate_better"]]
            lines.append(f"- {kind}, bivariate worse than the RBF: " + (", ".join(worse) or "none"))
        if "sweep" in block:
            lines += [
                "",
                "Settings (protocol captures, every third train material; mean ΔE76):",
                "",
            ]
            lams = SWEEP["smoothing"]
            lines += ["| log_eps \\ smoothing | " + " | ".join(f"{v:g}" for v in lams) + " |"]
            lines += ["|---" * (len(lams) + 1) + "|"]
            for eps in SWEEP["log_eps"]:
                cells = [
                    f"{r['de76']:.3f}"
                    for r in block["sweep"]
                    if r["log_eps"] == eps and r["smoothing"] in lams
                ]
                lines.append(f"| {eps:g} | " + " | ".join(cells) + " |")
        if "width_sweep" in block:
            kinds = list(dict.fromkeys(r["kind"] for r in block["width_sweep"]))
            lines += [
                "",
                "Pair width (degrees; 0: the spline alone; the same materials; mean ΔE76):",
                "",
                "| capture \\ pair_width | " + " | ".join(f"{w:g}" for w in WIDTHS) + " |",
                "|---" * (len(WIDTHS) + 1) + "|",
            ]
            for kind in kinds:
                cells = [f"{r['de76']:.3f}" for r in block["width_sweep"] if r["kind"] == kind]
                lines.append(f"| {kind} | " + " | ".join(cells) + " |")
    if payload["mode"] == "quick":
        lines += ["", "Quick run: a smoke test of the harness, not figures to quote."]
    return "\n".join(lines) + "\n"


def chart(payload: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    block = payload["sets"]["merl-test"]["kinds"]
    fig, axes = plt.subplots(1, len(block), figsize=(3.6 * len(block), 3.6), squeeze=False)
    for ax, (kind, r) in zip(axes[0], block.items()):
        names = list(r["rbf"]["per_material"])
        x = [r["rbf"]["per_material"][n]["de76"] for n in names]
        y = [r["bivariate"]["per_material"][n]["de76"] for n in names]
        top = max(max(x), max(y)) * 1.1
        ax.loglog(x, y, "o", ms=3)
        ax.plot([0.3, top], [0.3, top], "k:", lw=0.8)
        ax.set_xlabel("RBF (iso) ΔE76")
        ax.set_ylabel("bivariate ΔE76")
        ax.set_title(f"MERL test, {kind}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None, log=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 materials a split, 2 kinds")
    ap.add_argument("--out", type=Path, default=RESULTS, help="results folder")
    args = ap.parse_args(argv)
    log = log or (lambda s: print(s, flush=True))
    suffix = "_quick" if args.quick else ""
    payload = {
        "mode": "quick" if args.quick else "full",
        "command": " ".join(["python -m benchmarks.bivariate", *(argv or sys.argv[1:])]),
        "machine": machine(),
        "load_before": load_average(),
        "defaults": {
            k: aj.reconstruct_bivariate.__kwdefaults__[k]
            for k in ("log_eps", "smoothing", "pair_width")
        },
    }
    t0 = time.perf_counter()
    payload |= run(args.quick, log)
    payload["seconds"] = time.perf_counter() - t0
    payload["load_after"] = load_average()
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / f"bivariate{suffix}.json", payload)
    md = markdown(payload)
    (args.out / f"bivariate{suffix}.md").write_text(md)
    chart(payload, args.out / f"bivariate{suffix}.png")
    log(md)
    return payload


if __name__ == "__main__":
    main()
