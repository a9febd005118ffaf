"""What a finite-input check costs on the compiled operator's hot path (issue 16, "status inside
jit").

Run: ``python -m benchmarks.finite_check [--quick]``; writes
``benchmarks/results/finite_check{_quick}.{json,md}`` and prints the table.

The compiled operator (:func:`abrdf_jax.compile_operator`, ``preset("operator", "iso102")``,
float32, compact inputs ``(B, n_in, 3)``) is called inside one jitted function per variant:

- ``plain``: ``op(x)``;
- ``error_if``: ``op(eqx.error_if(x, ~isfinite(x), ...))``: a non-finite input raises at run time
  (Equinox's runtime error), also inside a user's ``jit``;
- ``status``: ``(op(x), all(isfinite(x)))``: a flag returned beside the tables;
- ``host check``: ``op(x)``, then :func:`abrdf_jax.check_finite` on the result in numpy (what
  the command line does before it writes; outside any ``jit``).

Time per call = the median (and the fastest) of repeated calls after a warm-up, with
``block_until_ready``; compile time apart. The overhead is against ``plain`` in the same run,
the variants called in turn so that a change of load hits them alike.
"""

from __future__ import annotations

import argparse
import statistics
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import get_material

from ._common import RESULTS, load_average, machine, write_json


def _variants():
    def plain(op, x):
        return op(x)

    def error_if(op, x):
        return op(eqx.error_if(x, ~jnp.isfinite(x), "non-finite sample value"))

    def status(op, x):
        return op(x), jnp.all(jnp.isfinite(x))

    jitted = {k: eqx.filter_jit(f) for k, f in (("plain", plain), ("error_if", error_if))}
    jitted["status"] = eqx.filter_jit(status)

    def host_check(op, x):
        res = jitted["plain"](op, x)
        aj.check_finite(res)
        return res

    return {**jitted, "host check": host_check}


def _block(r):
    return jax.block_until_ready(r)


def run(quick: bool = False) -> dict:
    config = aj.preset("operator", "iso102")
    params = aj.Params.default(config, dtype=jnp.float32)
    template = aj.sample(get_material("ggx-plastic"), config, params, as_measurements=True)
    op = aj.compile_operator(config, params, template, dtype=jnp.float32)
    one = np.asarray(op.compact(template))
    rng = np.random.default_rng(0)
    variants = _variants()
    batches = (1, 100) if quick else (1, 100, 1000)
    reps = 5 if quick else 25
    rows = []
    for b in batches:
        x = jnp.asarray(one[None] * rng.uniform(0.5, 2.0, (b, 1, 1)).astype(np.float32))
        compile_s, times = {}, {k: [] for k in variants}
        for name, f in variants.items():
            t0 = time.perf_counter()
            _block(f(op, x))
            compile_s[name] = time.perf_counter() - t0
        for _ in range(reps):
            for name, f in variants.items():  # in turn: the load changes alike for each
                t0 = time.perf_counter()
                _block(f(op, x))
                times[name].append(time.perf_counter() - t0)
        base = statistics.median(times["plain"])
        for name, ts in times.items():
            med = statistics.median(ts)
            rows.append(
                {
                    "batch": b,
                    "variant": name,
                    "median_ms": 1e3 * med,
                    "min_ms": 1e3 * min(ts),
                    "overhead_pct": 100 * (med / base - 1),
                    "first_call_s": compile_s[name],
                }
            )
    # the check works: a NaN input raises under error_if and sets the status flag
    bad = jnp.asarray(one[None]).at[0, 3, 1].set(jnp.nan)
    try:
        _block(variants["error_if"](op, bad))
        raised = False
    except Exception:  # noqa: BLE001 - Equinox's runtime error (an XlaRuntimeError subclass)
        raised = True
    flag = bool(variants["status"](op, bad)[1])
    return {
        "machine": machine(),
        "loadavg": load_average(),
        "n_in": int(op.n_inputs),
        "reps": reps,
        "rows": rows,
        "nan_input_raised_by_error_if": raised,
        "nan_input_status_flag": flag,
    }


def report(result: dict) -> str:
    lines = [
        "# Finite-input check on the compiled operator (float32, iso102, `operator` preset)",
        "",
        f"load average at the end: {', '.join(f'{v:.2f}' for v in result['loadavg'])}; "
        f"{result['reps']} calls per variant; n_in = {result['n_in']}; "
        f"devices {result['machine']['jax_devices']}",
        "",
        "| batch | variant | median ms | fastest ms | overhead vs plain | first call s |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['batch']} | {r['variant']} | {r['median_ms']:.3f} | {r['min_ms']:.3f} | "
            f"{r['overhead_pct']:+.1f} % | {r['first_call_s']:.2f} |"
        )
    lines += [
        "",
        f"A NaN input raised under `error_if`: {result['nan_input_raised_by_error_if']}; "
        f"the status flag was {result['nan_input_status_flag']} (False: not all finite).",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    result = run(args.quick)
    name = "finite_check" + ("_quick" if args.quick else "")
    write_json(name + ".json", result)
    text = report(result)
    (RESULTS / f"{name}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
