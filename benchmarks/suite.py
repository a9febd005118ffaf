"""Speed against accuracy: every method and setting of the package, and its peers, in one run.

Run: ``python -m benchmarks [--quick | --smoke] [--out DIR]`` (same as ``python -m benchmarks.suite``).
Writes ``suite.json`` (``suite_quick.json``, ``suite_smoke.json``), the table ``suite.md`` and the
charts ``speed_accuracy.png`` and ``throughput_batch.png`` (``_quick``/``_smoke``) to
``benchmarks/results`` (or ``--out``).

Every point is one *configuration* (a method with its settings on one sample layout) run on the
MERL/Nielsen **test** split (PROTOCOL.md: samples from the neural fits at the exact slice angles,
metrics of ``abrdf_jax.metrics``; nothing is chosen on test). For each point:

- **time per ABRDF**: the whole batch of test materials in one call, after a warm-up call,
  ``block_until_ready``, median of repeats (5 calls, or fewer once 2 s are spent; 0.5 s in quick
  mode) divided by the batch size; compile time (first call minus a steady call) and set-up (training a prior) apart;
- **accuracy**: mean ΔE76 and LogErr (and ΔE2000, RMSE8, PSNR) over the materials.

The full run covers iso102 and aniso204; sample budgets from 48 to 400 (fewer or more samples per
slice on the protocol's four elevation pairs, and nine elevation pairs); the subspace rules of
aniso204 (filip2012 = eq. 4, average, crossing, log); RBF kernels with the train-chosen widths of
``Params.default`` (linear and log values); parameterizations (onion, spherical, half/diff);
float32 against float64; the peers: the numpy/scipy implementation (``scipy_peer``), the PCA
prior (``pca_peer``), the analytic GGX/Ward fits (``analytic_peer``) and filling with the sample
mean. The peers and the two package presets also run on the package's analytic anisotropic
materials (dataset ``analytic-aniso``, synthetic; reported in the JSON, not on the chart).

``--quick`` runs a subset of configurations on 12 test materials (a few minutes on 2 cores);
``--smoke`` 3 configurations on 2 materials and a small throughput part (the CI smoke test).

After the points, the suite measures the compiled operator's throughput against batch size, the
machine's GEMM roofline, the single-material latency and peak memory in the same run
(:mod:`benchmarks.throughput`; ``"throughput"`` in the JSON, ``throughput_batch.png``), and
checks the issue's figures against the scipy peer's point of the same run (``"targets"``). Float64 points need
``jax_enable_x64``, which the suite switches on; float32 points keep float32 inputs and
parameters, and their compiled code holds no float64 array operations (checked when this was
written; the output dtype is checked at run time).

**Adding points** (e.g. a compiled operator or tuned parameters): register an :class:`Entry`
before calling :func:`main`::

    from benchmarks import suite
    suite.register(suite.Entry("operator recommended", "operator", "iso102",
                               build=lambda ctx, layout, dtype: lambda batch: my_op(batch.meas),
                               modes=("full", "quick")))
    suite.main(["--quick"])

or :func:`pipeline_entry` with a ``params`` callable (``(config, dtype) -> Params``), or
:func:`params_file_entry` with a parameter file of ``abrdf-jax fit`` (tuned widths, λ, α).

The suite's parts, one file each: ``_suite_layouts`` (sample layouts, the batch, the run's data),
``_suite_registry`` (:class:`Entry`, :data:`REGISTRY`, entry builders), ``_suite_entries`` (the
default entries and the peers' builders), ``_suite_run`` (timing one entry, the run's facts, Pareto
fronts, targets), ``_suite_charts`` and ``_suite_report`` (charts, markdown); this module is the
command line and re-exports the names above.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax

from ._common import RESULTS, machine, write_json
from ._suite_charts import GROUP_STYLE, plot, plot_throughput
from ._suite_entries import register_defaults
from ._suite_layouts import (
    LAYOUTS,
    N_MATERIALS,
    Batch,
    Context,
    Layout,
    sample_materials,
    sample_models,
)
from ._suite_registry import (
    REGISTRY,
    Entry,
    default_params,
    params_file_entry,
    pipeline_entry,
    register,
    selected_entries,
    tuned_params,
)
from ._suite_report import summary, table, write_outputs
from ._suite_run import MIN_TIME, loadavg, pareto, run_entry, targets_check, threads, versions

__all__ = [
    "GROUP_STYLE",
    "LAYOUTS",
    "MIN_TIME",
    "MODES",
    "N_MATERIALS",
    "REGISTRY",
    "Batch",
    "Context",
    "Entry",
    "Layout",
    "default_params",
    "main",
    "pareto",
    "params_file_entry",
    "pipeline_entry",
    "plot",
    "plot_throughput",
    "register",
    "run_entry",
    "sample_materials",
    "sample_models",
    "selected_entries",
    "summary",
    "table",
    "targets_check",
    "threads",
    "tuned_params",
    "versions",
    "write_outputs",
]

MODES = ("full", "quick", "smoke")
DATASETS = ("merl-test", "analytic-aniso")
METRICS = ("de76", "logerr", "de2000", "rmse8", "psnr")

register_defaults()


OTHER_SCRIPTS = """other benchmark scripts:
  python -m benchmarks.merl_accuracy [--quick]   accuracy on the MERL split (settings chosen on train)
  python -m benchmarks.speed [--quick]           one ABRDF and a batch beside the scipy peer
  python -m benchmarks.throughput [--quick]      fixed-parameter operator: ABRDFs/s against batch size
  python -m benchmarks.tuning [--quick]          gradient tuning of widths, λ and α
  python -m benchmarks.pca_peer [--quick]        the PCA peer: cross-validated choice on train, test figures
  python -m benchmarks.prior [--quick]           the package's learned priors (default, MERL-train) vs the RBF
  python -m benchmarks.analytic_peer [--quick]   the analytic peer: model and ε chosen on train, test figures
  python -m benchmarks.btf [--quick]             whole BTFs: throughput, roofline, per-texel error
  python -m benchmarks.model_selection [--quick] automatic model choice: confusion, error, cost (issue 6)
  python -m benchmarks.stability [--quick]       numerical edges: conditioning, data edges, method failures
  python -m benchmarks.peer_stability [--quick]  the analytic peer's anisotropic fits: starts, noise, mismatch
  python -m benchmarks.render [--quick]          Mitsuba 3 renders: s/image per variant, the README figure
  python -m benchmarks.captures [--quick]        real captures through the CLI: dense, jitter, noise, geometry
  python -m benchmarks.spike_cap [--quick]       how Config.spike_cap was chosen (MERL train, five capture kinds)
  python -m benchmarks.faults [--quick]          killed at any point: SIGKILL reconstruct DIR, btf reconstruct, fit; rerun, compare
  python -m benchmarks.load [--quick]            10,000 files and a 20 MiB CSV: peak memory, files/s, progress
"""


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=OTHER_SCRIPTS,
    )
    g = ap.add_mutually_exclusive_group()
    g.add_argument(
        "--quick", action="store_true", help="a subset of configurations on 12 test materials"
    )
    g.add_argument(
        "--smoke", action="store_true", help="3 configurations on 2 materials (the CI smoke test)"
    )
    ap.add_argument(
        "--out", type=Path, default=RESULTS, help="output folder (default benchmarks/results)"
    )
    ap.add_argument(
        "--only", nargs="*", help="run the entries whose name contains one of these strings"
    )
    ap.add_argument("--no-plot", action="store_true", help="skip the PNG charts")
    ap.add_argument(
        "--no-throughput", action="store_true", help="skip the operator throughput/roofline part"
    )
    ap.add_argument(
        "--list", action="store_true", help="list the registered configurations and exit"
    )
    ap.add_argument(
        "--replot",
        action="store_true",
        help="redraw the charts and table from the stored JSON, no run",
    )
    ap.add_argument(
        "--update",
        action="store_true",
        help="with --only: rerun those entries and merge them into the stored JSON (throughput kept)",
    )
    return ap


def run_points(ctx: Context, entries: list[Entry], log) -> list[dict]:
    """One JSON point per entry and dataset (the analytic dataset in full mode only); failures are points too."""
    points = []
    for entry in entries:
        for ds in entry.datasets:
            if ds != "merl-test" and ctx.mode != "full":
                continue
            try:
                p = run_entry(ctx, entry, ds, min_time=MIN_TIME[ctx.mode])
            except Exception as exc:  # a failing configuration is reported, not fatal
                log(f"  FAILED {entry.name} [{ds}]: {type(exc).__name__}: {exc}")
                points.append(
                    dict(
                        name=entry.name,
                        group=entry.group,
                        dataset=ds,
                        layout=entry.layout,
                        error=f"{type(exc).__name__}: {exc}",
                    )
                )
                continue
            points.append(p)
            log(
                f"  {p['name']:42s} [{ds}] {p['seconds_per_abrdf'] * 1e3:9.3f} ms/ABRDF  dE76 {p['de76']:6.2f}  "
                f"LogErr {p['logerr']:.3f}  (compile {p['compile_seconds']:.1f} s, set-up {p['setup_seconds']:.1f} s)"
            )
    return points


def mark_pareto(points: list[dict]) -> dict:
    """The Pareto fronts per dataset and metric; flags ``pareto_de76``/``pareto_logerr`` on the points."""
    ok = [p for p in points if "error" not in p]
    fronts = {
        ds: {m: pareto([p for p in ok if p["dataset"] == ds], m) for m in ("de76", "logerr")}
        for ds in sorted({p["dataset"] for p in ok})
    }
    for p in ok:
        for m in ("de76", "logerr"):
            p[f"pareto_{m}"] = p["name"] in fronts[p["dataset"]][m]
    return fronts


def main(argv=None, log=None) -> dict:
    """The command line (``python -m benchmarks --help``); returns the run's payload."""
    ap = _parser()
    args = ap.parse_args(argv)
    mode = "smoke" if args.smoke else "quick" if args.quick else "full"
    suffix = "" if mode == "full" else f"_{mode}"
    log = log or (lambda *a: print(*a, file=sys.stderr, flush=True))
    if args.update and not args.only:
        ap.error("--update needs --only NAME ...")
    if args.replot:
        payload = json.loads((args.out / f"suite{suffix}.json").read_text())
        write_outputs(payload, args.out, plots=not args.no_plot)
        return payload
    if args.list:
        for e in REGISTRY.values():
            print(f"{e.name:45s} {e.group:18s} {e.layout:14s} {e.dtype:8s} {','.join(e.modes)}")
        return {}
    jax.config.update("jax_enable_x64", True)  # for the float64 points; float32 points stay float32
    t0 = time.time()
    load_before = loadavg()
    ctx = Context(mode, log=log)
    log(f"suite ({mode}): data loaded in {ctx.load_seconds:.1f} s")
    points = run_points(ctx, selected_entries(mode, args.only), log)
    tp = None
    stored = None
    if (
        args.update
    ):  # merge into the stored run: same-named points replaced, its throughput part kept
        stored = json.loads((args.out / f"suite{suffix}.json").read_text())
        new = {(p["name"], p["dataset"]) for p in points}
        points = [p for p in stored["points"] if (p["name"], p["dataset"]) not in new] + points
        tp = stored.get("throughput")
    if not args.no_throughput and not args.update:
        from . import throughput

        log(f"suite ({mode}): operator throughput against batch size, roofline")
        t = time.perf_counter()
        tp = throughput.measure(mode, log=log)
        tp["seconds"] = time.perf_counter() - t
        tp["targets"] = targets_check(tp, points)
    fronts = mark_pareto(points)
    payload = dict(
        suite="abrdf_jax speed/accuracy",
        mode=mode,
        machine=machine(),
        threads=threads(),
        versions=versions(),
        dtype_note="float32 unless the point says float64 (jax_enable_x64 is on for those; float32 inputs and "
        "parameters stay float32)",
        timing="time per ABRDF = median batch time after a warm-up call / batch size; compile and set-up apart",
        materials={ds: ctx.names[ds] for ds in ctx.names},
        layouts={k: dataclasses.asdict(v) | {"n_samples": v.n_samples} for k, v in LAYOUTS.items()},
        points=points,
        pareto=fronts,
        throughput=tp,
        load_average_before=load_before,
        load_average_after=loadavg(),
        seconds=time.time() - t0,
    )
    if stored is not None:
        update = dict(
            date=payload["machine"]["date"],
            entries=sorted({e.name for e in selected_entries(mode, args.only)}),
            load_average_before=load_before,
            load_average_after=payload["load_average_after"],
            seconds=payload["seconds"],
        )
        payload.update(
            {
                k: stored[k]
                for k in (
                    "machine",
                    "threads",
                    "versions",
                    "load_average_before",
                    "load_average_after",
                    "seconds",
                )
                if k in stored
            }
        )
        payload["updates"] = stored.get("updates", []) + [update]
    write_json(args.out / f"suite{suffix}.json", payload, indent=1)
    write_outputs(payload, args.out, plots=not args.no_plot)
    n_ok = sum("error" not in p for p in points)
    log(
        f"suite ({mode}): {n_ok} points, {len(points) - n_ok} failed, {payload['seconds']:.0f} s; "
        f"wrote {args.out / f'suite{suffix}.json'}"
    )
    return payload


if __name__ == "__main__":
    main()
