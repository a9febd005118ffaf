"""Shared helpers of the benchmark scripts: data, sampling, evaluation, machine description."""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import load_tables81, stack_nbrdf, load_nbrdf_all
from abrdf_jax.metrics import evaluate_batch

from ._loadavg import load_average as load_average  # re-exported: one copy

RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """Machine, device, thread and version facts stored beside every figure."""
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "jax_devices": [str(d) for d in jax.devices()],
        "jax": jax.__version__,
        "numpy": np.__version__,
        "x64": bool(jax.config.jax_enable_x64),
        "threads_env": {
            k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "XLA_FLAGS") if os.environ.get(k)
        },
    }


def merl_split(split: str, data_dir=None):
    """Names, stacked neural models and reference tables of a PROTOCOL split."""
    t = load_tables81(data_dir)
    idx = np.nonzero(t["split"] == split)[0]
    names = [str(n) for n in t["names"][idx]]
    models = stack_nbrdf(load_nbrdf_all(names, data_dir))
    return names, models, jnp.asarray(t["abrdf"][idx]), [str(g) for g in t["group"][idx]]


def sample_batch(models, config, params=None) -> aj.Measurements:
    """PROTOCOL slice samples of every stacked model (exact angles, vmapped)."""
    params = params or aj.Params.default(config)
    return jax.jit(jax.vmap(lambda m: aj.sample(m, config, params, as_measurements=True)))(models)


def median_seconds(call, repeats: int = 5, warmup: bool = True) -> float:
    """Median wall seconds of ``call()`` over ``repeats`` calls, each waited for
    (``jax.block_until_ready``), after one untimed warm-up call unless ``warmup=False``."""
    if warmup:
        jax.block_until_ready(call())
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(call())
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def operator_flops(op, batch: int) -> tuple[float, float]:
    """``(dense, executed)`` flops of ``batch`` materials (3 channels) through a compiled
    operator's matrix product: the dense ``(q, n_in)`` product's, which the roofline fractions
    use (a rate in ABRDFs normalised by the machine's GEMM rate), and what runs: through the
    low-rank factors ``op.factors`` where the operator has them (``r · (q + n_in)`` a row)."""
    q, f = op.matrix.shape
    dense = 2.0 * q * f * 3 * batch
    if op.factors is None:
        return dense, dense
    return dense, 2.0 * sum(int(a.size) for a in op.factors) * 3 * batch


def metrics_of(rec, ref) -> dict:
    m = evaluate_batch(jnp.asarray(rec), jnp.asarray(ref))
    return {k: np.asarray(v) for k, v in m.items()}


def mean_metrics(per: dict) -> dict:
    return {k: float(np.mean(v)) for k, v in per.items()}


def metric_cells(r: dict) -> str:
    """ΔE76, LogErr, ΔE2000 and PSNR of a metrics dict as Markdown table cells."""
    return f"{r['de76']:.2f} | {r['logerr']:.3f} | {r['de2000']:.2f} | {r['psnr']:.1f}"


def mean_fill(meas: aj.Measurements) -> jnp.ndarray:
    """The trivial reconstruction of stacked measurements: every value is the mean of the samples (per channel)."""
    mean = (
        jnp.sum(jnp.where(meas.mask[..., None], meas.y, 0), axis=(1, 2))
        / jnp.sum(meas.count, axis=1)[:, None]
    )
    return jnp.broadcast_to(mean[:, None, None, :], (mean.shape[0], 81, 81, 3))


def write_json(name: str | Path, payload: dict, indent: int = 2) -> Path:
    """Write ``payload`` atomically to ``RESULTS / name``, or to ``name`` when it is a :class:`Path`."""
    path = name if isinstance(name, Path) else RESULTS / name
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload, indent=indent, default=float))
    os.replace(tmp, path)
    return path


def timed_run(stem: str, run, markdown, key: str = "results", **settings) -> dict:
    """Run ``run()`` between two readings of the load average and store its results beside the
    machine's facts: ``results/STEM.json`` (``settings``, the results under ``key``, load,
    seconds) and ``results/STEM.md`` (``markdown(payload)``, also printed). Returns the payload."""
    t0 = time.time()
    load_before = load_average()
    results = run()
    payload = dict(
        machine=machine(),
        **settings,
        load_before=load_before,
        load_after=load_average(),
        seconds=time.time() - t0,
        **{key: results},
    )
    write_json(f"{stem}.json", payload)
    md = markdown(payload)
    (RESULTS / f"{stem}.md").write_text(md)
    print(md)
    return payload
