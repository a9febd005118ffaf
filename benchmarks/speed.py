"""Speed of one reconstruction and of a batch, beside the numpy/scipy peer, in one run.

Run: ``python -m benchmarks.speed [--quick]``. Writes ``benchmarks/results/speed.json``.
Times are wall-clock after a warm-up call (compile time reported apart), JAX results
``block_until_ready``; median of repeats. Data: the package's embedded analytic materials (no
download), iso102, float32 for JAX (the package default) and float64 for scipy (its only mode).
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import default_materials

from ._common import machine, median_seconds, write_json
from .scipy_peer import reconstruct_samples


def timeit(fn, repeats):
    """Median seconds of ``fn()`` (the callers warm up on another input first)."""
    return median_seconds(fn, repeats, warmup=False)


def measurements(n, cfg):
    mats = list(default_materials().values())
    base = [aj.sample(m, cfg, as_measurements=True) for m in mats]
    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        m = base[k % len(base)]
        out.append(m.replace(y=m.y * float(rng.uniform(0.5, 2.0))))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="fewer repeats and a 10-material scipy batch"
    )
    ap.add_argument("--batch", type=int, default=100)
    args = ap.parse_args(argv)
    reps = 3 if args.quick else 10
    out = dict(machine=machine(), quick=args.quick, batch=args.batch, configs={})
    items = measurements(args.batch, aj.Config())
    stacked = aj.stack_measurements(items)
    for label, cfg in (("paper", aj.Config()), ("recommended", aj.Config.recommended())):
        p = aj.Params.default(cfg)
        t = time.perf_counter()
        jax.block_until_ready(aj.reconstruct(items[0], cfg, p))
        compile_single = time.perf_counter() - t
        single = timeit(lambda: aj.reconstruct(items[1], cfg, p), reps * 2)
        t = time.perf_counter()
        jax.block_until_ready(aj.reconstruct_batch(stacked, cfg, p))
        compile_batch = time.perf_counter() - t
        batch = timeit(lambda: aj.reconstruct_batch(stacked, cfg, p), reps)
        out["configs"][label] = dict(
            config=repr(cfg),
            compile_s_single=compile_single,
            seconds_per_abrdf=single,
            compile_s_batch=compile_batch,
            batch_seconds=batch,
            abrdfs_per_second_batch=args.batch / batch,
        )
        print(
            f"jax {label}: {single * 1e3:.1f} ms per ABRDF, batch of {args.batch}: "
            f"{args.batch / batch:.1f} ABRDF/s (compile {compile_single:.1f} s / {compile_batch:.1f} s)",
            flush=True,
        )
    # the scipy peer, same materials, iso102, the paper's method with its train-selected widths and λ
    n_sc = 10 if args.quick else args.batch
    flat = [m.to_samples() for m in items[:n_sc]]
    paper = aj.Config()
    p_paper = aj.Params.default(paper)
    call = lambda s: reconstruct_samples(s, paper, p_paper)  # noqa: E731
    call(flat[0])
    single_sc = timeit(lambda: call(flat[1]), reps)
    t = time.perf_counter()
    for s in flat:
        call(s)
    batch_sc = time.perf_counter() - t
    out["scipy_peer"] = dict(
        seconds_per_abrdf=single_sc,
        batch_size=n_sc,
        batch_seconds=batch_sc,
        abrdfs_per_second_batch=n_sc / batch_sc,
    )
    print(
        f"scipy peer: {single_sc * 1e3:.1f} ms per ABRDF, {n_sc / batch_sc:.2f} ABRDF/s over {n_sc} materials"
    )
    for label, r in out["configs"].items():
        r["speedup_vs_scipy_single"] = single_sc / r["seconds_per_abrdf"]
        r["speedup_vs_scipy_batch"] = (
            r["abrdfs_per_second_batch"] / out["scipy_peer"]["abrdfs_per_second_batch"]
        )
        print(
            f"  {label}: {r['speedup_vs_scipy_single']:.1f}x (single), {r['speedup_vs_scipy_batch']:.1f}x (batch)"
        )
    write_json("speed_quick.json" if args.quick else "speed.json", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
