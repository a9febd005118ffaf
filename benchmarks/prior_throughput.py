"""Throughput of the prior-only and the fused operators beside today's RBF operator, in the same
run (issue 14).

Run: ``python -m benchmarks.prior_throughput [--quick]``; writes
``benchmarks/results/prior_throughput{_quick}.json`` and prints a table.

What is measured (float32, one sample layout, the CPU threads the machine gives numpy/XLA):
ABRDFs per second against batch size ``B`` of

- **the command line's operator path** (:func:`abrdf_jax.compile_numpy_operator`, numpy, what
  ``abrdf-jax reconstruct`` applies to a folder of one layout; timed in a child interpreter that
  never imports JAX, as a warm run): the RBF operator of the recommended
  settings (``preset("operator")``: one ``(6561, n)`` matrix on the log of the samples), the prior-only
  model of the default prior (map → ``K``-rank matrix → inverse map) and the fused model of the
  default prior at its fixed hyper-parameters (map → one ``(n + 1, 6561)`` matrix → inverse map,
  ``--model fused``);
- **today's RBF operator in JAX** (:func:`abrdf_jax.compile_operator`, as ``benchmarks.throughput``
  measures it), for reference.

The issue's target: the prior's and the fused operator at iso102, B = 100, at least 80 % of the RBF
operator's rate. Time = the fastest of repeated calls after a warm-up (the operators called in turn; on a
CPU shared with other jobs the fastest call is the stable figure, the median follows the load),
for the JAX operator the median; inputs: the layout's samples of a built-in
material, each batch member scaled at random.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials
from abrdf_jax import prior as P

from ._common import load_average, machine, write_json

REPO = Path(__file__).resolve().parents[1]

BATCHES = {"full": (1, 10, 100, 1000), "quick": (1, 100, 1000)}
MIN_TIME = {"full": 1.0, "quick": 0.3}
TARGET = 0.8  # prior / RBF at iso102, B = 100


def _time(fn, min_time: float, max_repeats: int = 50) -> float:
    ts = []
    while not ts or (sum(ts) < min_time and len(ts) < max_repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


_CHILD = r"""
import json, pickle, statistics, sys, time
import numpy as np
ops, batches, min_time = pickle.load(open(sys.argv[1], "rb"))
rng = np.random.default_rng(0)
out = {}
for budget, (entries, y0) in ops.items():
    for b in batches:
        y = (y0[None] * rng.uniform(0.5, 2.0, (b, 1, 1, 3))).astype(np.float32)
        ts = {name: [] for name in entries}
        for op in entries.values():
            op.apply(y)
        # the operators in turn, call by call: a change of the machine's load hits both alike
        while sum(map(sum, ts.values())) < min_time * len(ts) or len(ts["rbf"]) < 5:
            for name, op in entries.items():
                t = time.perf_counter()
                op.apply(y)
                ts[name].append(time.perf_counter() - t)
            if len(ts["rbf"]) >= 30:
                break
        for name, t in ts.items():  # the fastest call: what the code costs when the CPU is free
            out[f"{budget}/{b}/{name}"] = b / min(t)
out["jax_imported"] = "jax" in sys.modules
print(json.dumps(out))
"""


def _numpy_rates(ops: dict, batches, min_time: float) -> dict:
    """The numpy operators' rates, timed in a fresh interpreter that never imports JAX (as a warm
    ``abrdf-jax reconstruct`` runs them: in this process, after JAX's import, numpy's GEMM ran
    several times slower on the machine of 2026-12-02)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "ops.pkl"
        path.write_bytes(pickle.dumps((ops, list(batches), min_time)))
        env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        proc = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, env=env
        )
    if proc.returncode:
        raise RuntimeError(proc.stderr)
    rates = json.loads(proc.stdout.strip().splitlines()[-1])
    if rates.pop("jax_imported"):
        raise RuntimeError("the numpy timing child imported JAX")
    return rates


def measure(mode: str = "quick", log=print) -> dict:
    prior = P.default_prior()
    rng = np.random.default_rng(0)
    out: dict = {"batches": list(BATCHES[mode]), "budgets": {}}
    ops, jax_rates = {}, {}
    for budget in ("iso102", "aniso204"):
        cfg = aj.preset("operator", budget)  # recommended; aniso204 with the linear "average" rule
        params = aj.Params.default(cfg)
        meas = aj.sample(materials.get_material("ggx-plastic"), cfg, params, as_measurements=True)
        build = {}
        entries = {}
        for name, model, kw in (
            ("rbf", cfg, {}),
            ("prior", prior, {}),
            ("fused", prior, {"fused": True}),
        ):
            t = time.perf_counter()
            entries[name] = aj.compile_numpy_operator(model, meas, params, **kw)
            build[name] = time.perf_counter() - t
        ops[budget] = (entries, np.asarray(meas.y, np.float32))
        jop = aj.compile_operator(cfg, params, meas, dtype=jnp.float32)
        for b in BATCHES[mode]:
            y = np.asarray(meas.y, np.float32)[None] * rng.uniform(0.5, 2.0, (b, 1, 1, 3))
            yj = jnp.asarray(y, jnp.float32)
            jax.block_until_ready(jop(yj))
            jax_rates[budget, b] = b / _time(lambda: jop(yj), MIN_TIME[mode])
        out["budgets"][budget] = {
            "n_inputs": entries["rbf"].n_inputs,
            "prior_components": prior.n_components,
            "build_seconds": build,
        }
    rates = _numpy_rates(ops, BATCHES[mode], MIN_TIME[mode])
    for budget, b in ops.items():
        rows = []
        for n in BATCHES[mode]:
            row = {"batch": n, **{m: rates[f"{budget}/{n}/{m}"] for m in ("rbf", "prior", "fused")}}
            row["rbf_jax"] = jax_rates[budget, n]
            row["prior_over_rbf"] = row["prior"] / row["rbf"]
            row["fused_over_rbf"] = row["fused"] / row["rbf"]
            rows.append(row)
            log(
                f"  {budget} B={n:5d}: RBF {row['rbf']:9.0f}/s  prior {row['prior']:9.0f}/s "
                f"({row['prior_over_rbf']:.0%})  fused {row['fused']:9.0f}/s "
                f"({row['fused_over_rbf']:.0%})  RBF in JAX {row['rbf_jax']:9.0f}/s"
            )
        out["budgets"][budget]["rows"] = rows
    at100 = next(r for r in out["budgets"]["iso102"]["rows"] if r["batch"] == 100)
    out["target"] = {
        "iso102_B100_prior_over_rbf": at100["prior_over_rbf"],
        "iso102_B100_fused_over_rbf": at100["fused_over_rbf"],
        "needed": TARGET,
        "pass": bool(at100["prior_over_rbf"] >= TARGET),
        "fused_pass": bool(at100["fused_over_rbf"] >= TARGET),
    }
    return out


def table(res: dict) -> str:
    lines = [
        "| budget | batch | RBF operator (numpy) ABRDF/s | prior operator ABRDF/s | prior / RBF "
        "| fused operator ABRDF/s | fused / RBF | RBF operator (JAX) ABRDF/s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for budget, b in res["budgets"].items():
        for r in b["rows"]:
            lines.append(
                f"| {budget} | {r['batch']} | {r['rbf']:,.0f} | {r['prior']:,.0f} | "
                f"{r['prior_over_rbf']:.0%} | {r['fused']:,.0f} | {r['fused_over_rbf']:.0%} | "
                f"{r['rbf_jax']:,.0f} |"
            )
    t = res["target"]
    lines.append("")
    for what, ratio, ok in (
        ("prior", t["iso102_B100_prior_over_rbf"], t["pass"]),
        ("fused", t["iso102_B100_fused_over_rbf"], t["fused_pass"]),
    ):
        lines.append(
            f"Target (iso102, B = 100): {what} ≥ {t['needed']:.0%} of the RBF operator: "
            f"{ratio:.0%} ({'PASS' if ok else 'FAIL'})."
        )
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer batch sizes and repeats")
    args = ap.parse_args(argv)
    mode = "quick" if args.quick else "full"
    t0 = time.time()
    res = measure(mode, log=lambda s: print(s, flush=True))
    res |= {"mode": mode, "seconds": time.time() - t0, "load": load_average()}
    write_json(f"prior_throughput{'_quick' if args.quick else ''}.json", machine() | res)
    print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
