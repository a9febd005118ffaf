"""Throughput of the fixed-parameter operator against batch size, beside the machine's GEMM roofline.

Run: ``python -m benchmarks.throughput [--quick]`` (writes ``throughput.json``); the suite
(``python -m benchmarks``) runs the same measurement in its run and stores it under
``"throughput"`` of ``suite.json``.

What is measured (float32, the package default; CPU threads as the machine gives them):

- **ABRDFs per second against batch size** ``B`` (1 … 10,000) of :func:`abrdf_jax.compile_operator`
  for iso102 → 81×81×3: the paper preset (linear values) and the recommended preset
  (``value_space="logsamples"``: the log of the samples instead of the log after slice interpolation,
  which makes the recommended setting one matrix product; the suite measures its accuracy).
  Each call is one GEMM ``(3B, 102) · (102, 6561)`` plus the exp/clamp (for B above the
  operator's tile of 128 materials, a loop of tile-sized GEMMs whose products stay in cache);
  time = median of repeated calls after a warm-up, ``block_until_ready``. Two figures per batch:
  a fresh output per call (``op(x)``), and the output of the previous call reused
  (``op(x, out=previous)``, donated), which is what a stream of batches can do: a fresh
  787 MB output for B = 10,000 costs ~190,000 first-touch page faults, as much time as the
  product. The 1-minute load average is stored beside each row.
- **roofline**: the rate of ``jnp.matmul`` on the same machine in the same run, for the same
  GEMM shape without the element-wise work (``gemm_same_shape``) and for a square 2048³ product
  (``gemm_square``, the machine's practical peak; measured again after the operator rows,
  ``gemm_square_end``, to show how steady the machine was); the operator's *fraction* is its
  flop rate ``2 · 6561 · 102 · 3B / t`` over ``gemm_square``.
- **single-material latency** (B = 1) after compilation, and **compile time** apart (building the
  matrix: one RBF factorisation; compiling the apply function per batch shape).
- **cost against centres and targets**: building and applying (B = 100) the operator for sample
  budgets 48 … 400 (the RBF centres grow with the samples) and for 1,000 … 20,000 target
  direction pairs instead of the 6,561 of the UBO grid.
- **peak memory**: XLA's buffer sizes of the compiled apply function per batch size
  (arguments + outputs + temporaries, ``memory_analysis``) and the process's peak RSS.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import default_materials

from ._common import load_average, machine, operator_flops, write_json

BATCHES = {
    "full": (1, 10, 100, 1000, 3000, 10000),
    "quick": (1, 10, 100, 1000, 10000),
    "smoke": (1, 10),
}
BUDGETS = {
    "full": (12, 25, 50, 100),
    "quick": (12, 50),
    "smoke": (),
}  # samples per slice (iso: 4 slices)
TARGETS = {"full": (1000, 6561, 20000), "quick": (1000, 20000), "smoke": ()}
MIN_TIME = {"full": 1.0, "quick": 0.3, "smoke": 0.05}


def _time(fn, min_time: float, max_repeats: int = 20) -> tuple[float, int]:
    """Median seconds of ``fn()`` (blocked) over repeats until ``min_time`` is spent; fn is warm."""
    ts = []
    while not ts or (sum(ts) < min_time and len(ts) < max_repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), len(ts)


def _time_reused(op, x, min_time: float, max_repeats: int = 20) -> float:
    """Median seconds of ``op(x, out=previous)``: each call writes into the last call's output
    (donated), so no call pays first-touch page faults for a fresh buffer."""
    out = jax.block_until_ready(op(x))
    out = jax.block_until_ready(op(x, out=out))  # compiles the donating variant
    ts = []
    while not ts or (sum(ts) < min_time and len(ts) < max_repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(op(x, out=out))
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def gemm_rate(m: int, k: int, n: int, dtype=jnp.float32, min_time: float = 0.5) -> dict:
    """Measured flop rate of ``(m, k) · (k, n)`` with ``jnp.matmul`` (compiled, warm)."""
    a = jax.random.normal(jax.random.PRNGKey(0), (m, k), dtype)
    b = jax.random.normal(jax.random.PRNGKey(1), (k, n), dtype)
    f = jax.jit(lambda a, b: jnp.matmul(a, b, precision=jax.lax.Precision.HIGHEST))
    jax.block_until_ready(f(a, b))
    t, reps = _time(lambda: f(a, b), min_time)
    return dict(shape=[m, k, n], seconds=t, repeats=reps, gflops=2.0 * m * k * n / t / 1e9)


def numpy_gemm_rate(m: int, k: int, n: int, min_time: float = 0.5) -> dict:
    """The same product in numpy (its BLAS, e.g. OpenBLAS) into a preallocated output: what a
    library GEMM reaches at the operator's shape, beside XLA's (:func:`gemm_rate`)."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((m, k), dtype=np.float32)
    b = rng.standard_normal((k, n), dtype=np.float32)
    c = np.matmul(a, b)  # warm, and the output's pages touched once
    t, reps = _time(lambda: np.matmul(a, b, out=c), min_time)
    blas = np.show_config(mode="dicts").get("Build Dependencies", {}).get("blas", {})
    return dict(
        shape=[m, k, n],
        seconds=t,
        repeats=reps,
        gflops=2.0 * m * k * n / t / 1e9,
        blas=f"{blas.get('name', '?')} {blas.get('version', '')}".strip(),
    )


def _counts(per_slice: int | None):
    if per_slice is None:
        return aj.protocol_counts("iso102")
    return tuple(c for _ in aj.PROTOCOL_PAIRS for c in (0, per_slice))


def template(cfg: aj.Config, per_slice: int | None = None, dtype=jnp.float32) -> aj.Measurements:
    """Slice samples of one embedded analytic material on the protocol pairs (``per_slice`` per slice)."""
    mat = next(iter(default_materials().values()))
    alpha = jnp.asarray(np.deg2rad(aj.PROTOCOL_ALPHA_DEG), dtype)
    return aj.sample_model(mat, _counts(per_slice), alpha, cfg.pairs, dtype=dtype)


def values(op, meas: aj.Measurements, batch: int, seed: int = 0) -> jax.Array:
    """``(batch, n_in, 3)`` compact sample values: the template's, each material scaled at random."""
    base = op.compact(meas)
    scale = jax.random.uniform(jax.random.PRNGKey(seed), (batch, 1, 3), base.dtype, 0.5, 2.0)
    return jax.block_until_ready(base[None] * scale)


def memory_of(op, x) -> dict | None:
    """XLA's buffer sizes (bytes) of the operator's compiled apply function for input ``x``."""
    try:
        m = jax.jit(lambda v: op(v)).lower(x).compile().memory_analysis()
    except Exception:  # not every backend/version reports it
        return None
    if m is None:
        return None
    keys = (
        "argument_size_in_bytes",
        "output_size_in_bytes",
        "temp_size_in_bytes",
        "generated_code_size_in_bytes",
    )
    out = {k: int(getattr(m, k, 0) or 0) for k in keys}
    out["total_bytes"] = (
        out["argument_size_in_bytes"] + out["output_size_in_bytes"] + out["temp_size_in_bytes"]
    )
    return out


def peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1024 / 1024 if sys.platform == "darwin" else r / 1024


PRESETS = {
    "paper": lambda: aj.Config(),
    # the recommended setting made linear: the log of the samples (before slice interpolation) in place
    # of the log after it; not the same numbers (the suite measures both), the same widths and λ
    "recommended": lambda: aj.Config.recommended(value_space="logsamples"),
    # the same without the spike cap (Config.spike_cap): what the cap's second product costs
    "recommended-nocap": lambda: aj.Config.recommended(value_space="logsamples", spike_cap=None),
    # the recommended operator with its dense matrix product instead of its low-rank factors
    # (ReconstructionOperator.factors): what the factors gain, in the same run
    "recommended-dense": lambda: aj.Config.recommended(value_space="logsamples"),
}

#: Presets run with the dense product (their operator's ``factors`` dropped).
DENSE = ("recommended-dense",)


def _params(cfg: aj.Config, dtype) -> aj.Params:
    """``Params.default`` of the setting the operator stands for (``logsamples`` takes ``log``'s widths and λ)."""
    if cfg.value_space == "logsamples":
        cfg = aj.Config(
            **{**{f: getattr(cfg, f) for f in ("budget", "kernel", "degree")}, "value_space": "log"}
        )
    return aj.Params.default(cfg, dtype=dtype)


def measure(mode: str = "quick", log=print) -> dict:
    """Throughput, roofline, latency, scaling and memory of the operator path (see the module docstring)."""
    dtype = jnp.float32
    mt = MIN_TIME[mode]
    out: dict = dict(dtype="float32", batches=list(BATCHES[mode]), presets={})
    sq = 2048 if mode != "smoke" else 512
    out["gemm_square"] = gemm_rate(sq, sq, sq, dtype, min_time=mt)
    big = max(BATCHES[mode])
    out["gemm_same_shape"] = gemm_rate(3 * big, 102, 6561, dtype, min_time=mt)
    out["gemm_same_shape_numpy"] = numpy_gemm_rate(3 * big, 102, 6561, min_time=mt)
    peak = out["gemm_square"]["gflops"]
    log(
        f"  roofline: square GEMM {peak:.1f} GFLOP/s, same-shape GEMM "
        f"{out['gemm_same_shape']['gflops']:.1f} GFLOP/s (numpy's "
        f"{out['gemm_same_shape_numpy']['blas']}: {out['gemm_same_shape_numpy']['gflops']:.1f})"
    )
    for name, make in PRESETS.items():
        if mode == "smoke" and name != "paper":
            continue  # the smoke test checks that the part runs, one preset is enough
        cfg = make()
        meas = template(cfg, dtype=dtype)
        params = _params(cfg, dtype)
        t = time.perf_counter()
        op = jax.block_until_ready(aj.compile_operator(cfg, params, meas, dtype=dtype))
        if name in DENSE:
            op = eqx.tree_at(lambda o: o.factors, op, replace=None)
        build = time.perf_counter() - t
        rows = []
        for b in BATCHES[mode]:
            x = values(op, meas, b)
            t = time.perf_counter()
            jax.block_until_ready(op(x))
            first = time.perf_counter() - t
            sec, reps = _time(lambda: op(x), mt)
            reused = _time_reused(op, x, mt)
            flops, executed = operator_flops(op, b)  # dense-equivalent, what runs
            row = dict(
                batch=b,
                seconds=sec,
                repeats=reps,
                abrdfs_per_second=b / sec,
                compile_seconds=max(first - sec, 0.0),
                gflops=flops / sec / 1e9,
                executed_gflops=executed / sec / 1e9,
                fraction_of_roofline=flops / sec / 1e9 / peak,
                seconds_reused_output=reused,
                abrdfs_per_second_reused_output=b / reused,
                fraction_of_roofline_reused_output=flops / reused / 1e9 / peak,
                memory=memory_of(op, x),
                load_average=load_average()[0],
            )
            rows.append(row)
            log(
                f"  operator {name:11s} B={b:6d}: {b / sec:10.0f} ABRDF/s  {row['gflops']:6.1f} GFLOP/s "
                f"({row['fraction_of_roofline']:.0%} of the square GEMM); output reused: "
                f"{b / reused:10.0f} ABRDF/s ({row['fraction_of_roofline_reused_output']:.0%}); "
                f"load {row['load_average']:.1f}"
            )
            del x
        best = max(rows, key=lambda r: r["abrdfs_per_second"])
        out["presets"][name] = dict(
            config=repr(cfg),
            n_inputs=op.n_inputs,
            matrix_shape=list(op.matrix.shape),
            factor_rank=None if op.factors is None else int(op.factors[1].shape[0]),
            build_seconds=build,
            rows=rows,
            latency_seconds=rows[0]["seconds"],
            best_abrdfs_per_second=best["abrdfs_per_second"],
            best_batch=best["batch"],
            best_fraction_of_roofline=best["fraction_of_roofline"],
        )
    # The square GEMM again after the presets (the machine may be shared): compare the two
    # before trusting the fractions, which are taken against the first.
    out["gemm_square_end"] = gemm_rate(sq, sq, sq, dtype, min_time=mt)
    log(f"  square GEMM at the end: {out['gemm_square_end']['gflops']:.1f} GFLOP/s")
    # cost against the number of centres (sample budget) and of target directions; recommended preset
    cfg = PRESETS["recommended"]()
    params = _params(cfg, dtype)
    scaling = []
    for per in BUDGETS[mode]:
        meas = template(cfg, per, dtype)
        t = time.perf_counter()
        op = jax.block_until_ready(aj.compile_operator(cfg, params, meas, dtype=dtype))
        build = time.perf_counter() - t
        x = values(op, meas, 100)
        jax.block_until_ready(op(x))
        sec, _ = _time(lambda: op(x), mt)
        scaling.append(
            dict(
                kind="centres",
                n_samples=op.n_inputs,
                targets=int(op.matrix.shape[0]),
                build_seconds=build,
                batch=100,
                seconds=sec,
                abrdfs_per_second=100 / sec,
            )
        )
        log(
            f"  centres: {op.n_inputs:4d} samples: build {build:.2f} s, {100 / sec:.0f} ABRDF/s at B=100"
        )
    meas = template(cfg, dtype=dtype)
    rng = np.random.default_rng(0)
    for q in TARGETS[mode]:
        v = rng.normal(size=(2, q, 3))
        v[..., 2] = np.abs(v[..., 2])
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        t = time.perf_counter()
        op = jax.block_until_ready(
            aj.compile_operator(cfg, params, meas, dtype=dtype, targets=(v[0], v[1]))
        )
        build = time.perf_counter() - t
        x = values(op, meas, 100)
        jax.block_until_ready(op(x))
        sec, _ = _time(lambda: op(x), mt)
        scaling.append(
            dict(
                kind="targets",
                n_samples=op.n_inputs,
                targets=q,
                build_seconds=build,
                batch=100,
                seconds=sec,
                abrdfs_per_second=100 / sec,
            )
        )
        log(f"  targets: {q:6d}: build {build:.2f} s, {100 / sec:.0f} evaluations/s at B=100")
    out["scaling"] = scaling
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def _blas_note(tp: dict, square: dict) -> str:
    """The same shape in numpy's BLAS, where the run measured it (runs before 2026-12-06 did
    not): XLA's CPU GEMM is the operator's ceiling, not the machine's."""
    nb = tp.get("gemm_same_shape_numpy")
    if not nb:
        return ""
    return (
        f" in XLA ({tp['gemm_same_shape']['gflops'] / square['gflops']:.0%} of the square "
        f"GEMM), {nb['gflops']:.1f} GFLOP/s in numpy's {nb['blas']} "
        f"({nb['gflops'] / square['gflops']:.0%})"
    )


def table(tp: dict, scipy_seconds: float | None = None) -> str:
    """Markdown table of the throughput block (ABRDFs/s per batch size, fraction of the roofline)."""
    pre = tp["presets"]
    names = list(pre)
    lines = [
        "| batch | "
        + " | ".join(
            f"{n}: ABRDF/s | {n}: % of GEMM peak | {n}: % with the output reused" for n in names
        )
        + " | XLA buffers (MB) |",
        "|---" * (3 * len(names) + 2) + "|",
    ]
    for i, b in enumerate(tp["batches"]):
        cells = []
        for n in names:
            r = pre[n]["rows"][i]
            cells += [f"{r['abrdfs_per_second']:,.0f}", f"{100 * r['fraction_of_roofline']:.0f}"]
            reused = r.get("fraction_of_roofline_reused_output")
            cells.append("–" if reused is None else f"{100 * reused:.0f}")
        mem = pre[names[0]]["rows"][i].get("memory")
        lines.append(
            f"| {b} | " + " | ".join(cells) + f" | {mem['total_bytes'] / 2**20:.0f} |"
            if mem
            else f"| {b} | " + " | ".join(cells) + " | – |"
        )
    g, s = tp["gemm_square"], tp["gemm_same_shape"]
    end = tp.get("gemm_square_end")
    notes = [
        f"Roofline (same run): square {g['shape'][0]}³ GEMM {g['gflops']:.1f} GFLOP/s"
        + (f" at the start, {end['gflops']:.1f} at the end" if end else "")
        + f"; the operator's GEMM shape {s['shape']} alone {s['gflops']:.1f} GFLOP/s"
        + _blas_note(tp, g)
        + "."
    ]
    for n in names:
        p = pre[n]
        txt = (
            f"{n}: {p['best_abrdfs_per_second']:,.0f} ABRDF/s at B={p['best_batch']} "
            f"({100 * p['best_fraction_of_roofline']:.0f}% of the square-GEMM rate); single-material latency "
            f"{p['latency_seconds'] * 1e3:.2f} ms; building the {p['matrix_shape'][0]}×{p['matrix_shape'][1]} "
            f"matrix {p['build_seconds']:.2f} s"
        )
        if p.get("factor_rank"):
            txt += (
                f"; run through its rank-{p['factor_rank']} factors (the operator's `factors`: the "
                "fractions count the dense product's flops)"
            )
        if scipy_seconds:
            txt += (
                f"; {p['best_abrdfs_per_second'] * scipy_seconds:,.0f}× the scipy peer's ABRDFs/s"
            )
        notes.append(txt + ".")
    if tp.get("scaling"):
        notes.append(
            "Cost against centres/targets (recommended, B=100): "
            + "; ".join(
                f"{r['n_samples']} samples × {r['targets']} targets: build (with its compile) {r['build_seconds']:.2f} s, "
                f"{r['abrdfs_per_second']:,.0f}/s"
                for r in tp["scaling"]
            )
            + "."
        )
    notes.append(f"Peak RSS of the process: {tp['peak_rss_mb']:.0f} MB.")
    return "\n".join(lines) + "\n\n" + "\n".join(f"- {n}" for n in notes)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer batch sizes, budgets and repeats")
    args = ap.parse_args(argv)
    mode = "quick" if args.quick else "full"
    tp = measure(mode, log=lambda *a: print(*a, flush=True))
    write_json(
        "throughput_quick.json" if args.quick else "throughput.json",
        dict(machine=machine(), mode=mode, **tp),
    )
    print(table(tp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
