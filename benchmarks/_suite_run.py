"""Running the suite: set up, warm up, time and evaluate one entry; the run's facts (threads,
versions, load); the Pareto fronts and the issue's targets read off a run.

Part of the speed/accuracy suite (:mod:`benchmarks.suite`).
"""

from __future__ import annotations

import importlib.metadata
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from ._common import load_average, metrics_of
from ._suite_layouts import LAYOUTS, Context
from ._suite_registry import Entry

MIN_TIME = {
    "full": 2.0,
    "quick": 0.5,
    "smoke": 0.1,
}  # seconds of repeated timing per point (at most 5 calls)


def _block(x):
    return jax.block_until_ready(x) if isinstance(x, jax.Array) else x


def run_entry(
    ctx: Context, entry: Entry, dataset: str, min_time: float = 2.0, max_repeats: int = 5
) -> dict:
    """Set up, warm up, time and evaluate one entry on one dataset; returns the JSON point."""
    lay = LAYOUTS[entry.layout]
    dtype = jnp.float64 if entry.dtype == "float64" else jnp.float32
    batch = ctx.batch(dataset, lay, dtype)
    t = time.perf_counter()
    run = entry.build(ctx, lay, dtype)
    setup = time.perf_counter() - t
    t = time.perf_counter()
    out = _block(run(batch))
    first = time.perf_counter() - t
    times = [] if entry.jit else [first]
    while entry.jit and (len(times) < 1 or (sum(times) < min_time and len(times) < max_repeats)):
        t = time.perf_counter()
        _block(run(batch))
        times.append(time.perf_counter() - t)
    steady = statistics.median(times)
    out = np.asarray(out)
    if out.shape != (batch.size, 81, 81, 3):
        raise RuntimeError(
            f"{entry.name}: expected tables of shape {(batch.size, 81, 81, 3)}, got {out.shape}"
        )
    if entry.dtype == "float32" and out.dtype != np.float32:
        raise RuntimeError(f"{entry.name}: a float32 entry returned {out.dtype}")
    finite = bool(np.all(np.isfinite(out)))
    per = metrics_of(np.nan_to_num(out, nan=0.0, posinf=0.0).astype(np.float32), ctx.refs[dataset])
    return dict(
        name=entry.name,
        group=entry.group,
        dataset=dataset,
        layout=lay.name,
        budget=lay.budget,
        n_samples=lay.n_samples,
        dtype=entry.dtype,
        note=entry.note,
        n_materials=batch.size,
        seconds_per_abrdf=steady / batch.size,
        batch_seconds=steady,
        repeats=len(times),
        compile_seconds=max(first - steady, 0.0) if entry.jit else 0.0,
        setup_seconds=setup,
        finite=finite,
        **{k: float(np.mean(v)) for k, v in per.items()},
        per_material={k: [float(x) for x in per[k]] for k in ("de76", "logerr")},
    )


def pareto(points: list[dict], metric: str) -> list[str]:
    """Names of the points no other point beats in both time per ABRDF and ``metric`` (lower is better)."""
    front, best = [], np.inf
    for p in sorted(points, key=lambda p: (p["seconds_per_abrdf"], p[metric])):
        if p[metric] < best:
            front.append(p["name"])
            best = p[metric]
    return front


def versions() -> dict:
    """Versions of the packages behind the figures."""
    out = {}
    for pkg in (
        "jax",
        "jaxlib",
        "numpy",
        "scipy",
        "equinox",
        "optimistix",
        "lineax",
        "matplotlib",
        "abrdf_jax",
    ):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    out["python"] = sys.version.split()[0]
    return out


def threads() -> dict:
    """CPU count, affinity, load and the thread-related environment of the run."""
    env = (
        "OMP_NUM_THREADS",
        "OPENBLAS_NUM_THREADS",
        "MKL_NUM_THREADS",
        "XLA_FLAGS",
        "JAX_PLATFORMS",
    )
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    try:
        load = load_average()
    except OSError:
        load = None
    return dict(
        cpu_count=os.cpu_count(),
        affinity=affinity,
        load_average=load,
        env={k: os.environ[k] for k in env if k in os.environ},
    )


def loadavg():
    """The 1, 5 and 15 minute load averages (``None`` where the system has none)."""
    try:
        return load_average()
    except OSError:
        return None


def targets_check(tp: dict, points: list[dict]) -> dict:
    """The issue's figures read off one run: operator ABRDFs/s (iso102, B ≥ 1000), its ratio to the
    scipy peer's ABRDFs/s, the fraction of the measured GEMM roofline, the single-material latency."""
    scipy = [p for p in points if p.get("name") == "scipy peer (paper) iso102" and "error" not in p]
    scipy_rate = 1.0 / scipy[0]["seconds_per_abrdf"] if scipy else None
    out = dict(scipy_abrdfs_per_second=scipy_rate, presets={}, lines=[])
    for name, pre in tp["presets"].items():
        rate, frac, lat = (
            pre["best_abrdfs_per_second"],
            pre["best_fraction_of_roofline"],
            pre["latency_seconds"],
        )
        ratio = rate / scipy_rate if scipy_rate else None
        out["presets"][name] = dict(
            abrdfs_per_second=rate,
            batch=pre["best_batch"],
            ratio_to_scipy=ratio,
            fraction_of_roofline=frac,
            latency_seconds=lat,
            meets=dict(
                rate_5000=rate >= 5000,
                ratio_500=None if ratio is None else ratio >= 500,
                roofline_30=frac >= 0.3,
                latency_10ms=lat < 0.010,
            ),
        )
        out["lines"].append(
            f"operator {name}: {rate:,.0f} ABRDF/s at B={pre['best_batch']} (target ≥ 5,000); "
            + (
                f"{ratio:,.0f}× the scipy peer's {scipy_rate:.2f} ABRDF/s (target ≥ 500×); "
                if ratio
                else "scipy peer not in this run; "
            )
            + f"{100 * frac:.0f}% of the measured square-GEMM rate (aim ≥ 30%); single-material latency "
            f"{lat * 1e3:.2f} ms after compilation (target < 10 ms)."
        )
    return out
