"""Time and memory of the bivariate model on one measurement, against its number of samples.

Run: ``python -m benchmarks.bivariate_scaling [--quick]``. Writes
``benchmarks/results/bivariate_scaling.json``, ``.md`` and the chart ``.png`` (``_quick`` with
``--quick``).

A continuous capture records thousands of samples a slice (issue 12: "memory and time stay
bounded"). :func:`abrdf_jax.reconstruct_bivariate` applies the model's map in factors
(:func:`abrdf_jax._bivariate.bivariate_values`: the spline's coefficients of the samples, its
values at the targets, the residual curves' values); the layout map
(:func:`abrdf_jax._bivariate.bivariate_map`, what the command line and BTF chunks apply to many
measurements of one layout, and what the library call formed for one measurement before) has a
row per target and a column per sample. Both are timed here on captures of the analytic
``ggx-plastic`` (iso102, 0.3° jitter, seed 2) of 26 to 25,000 samples a diagonal slice, each
size in a process of its own: seconds (median of 3 after one warm-up call), numpy's peak
allocation during one call (``tracemalloc``), the process's peak RSS over its RSS before the
call, and ΔE76 against the dense truth (more samples must not make it worse). The map is run up
to :data:`MATRIX_MAX` samples (beyond, it takes minutes and gigabytes).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ._common import RESULTS, load_average, machine, write_json

MATERIAL = "ggx-plastic"
PER_SLICE = (None, 250, 2500, 10000, 25000)  # None: the protocol's 25/25/26/26
QUICK_PER_SLICE = (None, 250, 2500)
MATRIX_MAX = 10000
PATHS = ("factored", "map")


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child(per_slice: int | None, path: str) -> dict:
    """One size, one path, in this process: the figures of the module docstring."""
    import tracemalloc

    import abrdf_jax as aj
    from abrdf_jax import _bivariate as B
    from abrdf_jax import materials, metrics

    mat = materials.get_material(MATERIAL)
    s = aj.simulate_capture(
        mat, budget="iso102", per_slice=per_slice, jitter_deg=0.3 if per_slice else 0.0, seed=2
    )

    def call():
        if path == "factored":
            return aj.reconstruct_bivariate(s)
        ti, pi_, tv, pv, rgb = B._columns(s)
        m = B.bivariate_map(*B.source_vectors(ti, pi_, tv, pv))
        return B._values(m, rgb[None], np.cos(ti), B._grid()[2], B.LOG_EPS)[0].reshape(81, 81, 3)

    ref = materials.dense_table(mat)
    before = _rss_mib()
    table = call()  # warm-up (the grid's coordinates are made once)
    rss = _rss_mib() - before
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    tracemalloc.start()
    call()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return {
        "samples": len(s),
        "path": path,
        "seconds": float(np.median(times)),
        "tracemalloc_peak_mib": peak,
        "rss_added_mib": rss,
        "de76": float(metrics.evaluate(table, ref)["de76"]),
    }


def run(quick: bool, log) -> list[dict]:
    rows = []
    for per_slice in QUICK_PER_SLICE if quick else PER_SLICE:
        for path in PATHS:
            if path == "map" and per_slice and 4 * per_slice > MATRIX_MAX:
                continue
            cmd = [sys.executable, "-m", "benchmarks.bivariate_scaling", "--child"]
            cmd += [str(per_slice or 0), path]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            log(
                f"  {r['samples']:>7d} samples {path:8s} {r['seconds']:8.3f} s  "
                f"peak {r['tracemalloc_peak_mib']:8.1f} MiB (tracemalloc)  "
                f"RSS +{r['rss_added_mib']:7.1f} MiB  ΔE76 {r['de76']:.3f}"
            )
            rows.append(r)
    return rows


def markdown(payload: dict) -> str:
    lines = [
        f"# The bivariate model on one measurement: time and memory against samples "
        f"({payload['mode']} run)",
        "",
        f"`{payload['command']}`; {payload['machine']['date']}, "
        f"{payload['machine']['cpu_count']} CPUs, load "
        f"{payload['load_before']} → {payload['load_after']}, {payload['seconds']:.0f} s. "
        f"{MATERIAL}, iso102 captures (jitter 0.3° beyond the protocol's), each row a process "
        "of its own; seconds: median of 3 after a warm-up call; peak: numpy's allocations "
        "during one call (tracemalloc); RSS: the process's peak over its RSS before the first "
        "call. factored: `abrdf_jax.reconstruct_bivariate` (the map applied in factors); map: "
        "the layout map with a row per target and a column per sample, applied to the samples "
        "(what the library call formed before).",
        "",
        "| samples | path | s | peak MiB (tracemalloc) | RSS added MiB | ΔE76 |",
        "|---|---|---|---|---|---|",
    ]
    for r in payload["rows"]:
        lines.append(
            f"| {r['samples']} | {r['path']} | {r['seconds']:.3f} | "
            f"{r['tracemalloc_peak_mib']:.1f} | {r['rss_added_mib']:.0f} | {r['de76']:.3f} |"
        )
    if payload["mode"] == "quick":
        lines += ["", "Quick run: a smoke test of the harness, not figures to quote."]
    return "\n".join(lines) + "\n"


def chart(payload: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4))
    for name in PATHS:
        rows = [r for r in payload["rows"] if r["path"] == name]
        n = [r["samples"] for r in rows]
        axes[0].loglog(n, [r["seconds"] for r in rows], "o-", label=name)
        axes[1].loglog(n, [r["tracemalloc_peak_mib"] for r in rows], "o-", label=name)
    axes[0].set_ylabel("seconds per measurement")
    axes[1].set_ylabel("peak MiB (numpy, tracemalloc)")
    for ax in axes:
        ax.set_xlabel("samples in the capture")
        ax.legend(fontsize=8)
    fig.suptitle(f"bivariate model, one {MATERIAL} capture", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None, log=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="up to 10,000 samples")
    ap.add_argument("--out", type=Path, default=RESULTS, help="results folder")
    ap.add_argument("--child", nargs=2, metavar=("PER_SLICE", "PATH"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(int(args.child[0]) or None, args.child[1])))
        return {}
    log = log or (lambda s: print(s, flush=True))
    suffix = "_quick" if args.quick else ""
    payload = {
        "mode": "quick" if args.quick else "full",
        "command": " ".join(["python -m benchmarks.bivariate_scaling", *(argv or sys.argv[1:])]),
        "machine": machine(),
        "load_before": load_average(),
    }
    t0 = time.perf_counter()
    payload["rows"] = run(args.quick, log)
    payload["seconds"] = time.perf_counter() - t0
    payload["load_after"] = load_average()
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / f"bivariate_scaling{suffix}.json", payload)
    md = markdown(payload)
    (args.out / f"bivariate_scaling{suffix}.md").write_text(md)
    chart(payload, args.out / f"bivariate_scaling{suffix}.png")
    log(md)
    return payload


if __name__ == "__main__":
    main()
