"""Mitsuba 3 renders of reconstructions (issue 15): seconds per image for each variant that
works here, and the README figure.

Run: ``python -m benchmarks.render [--quick]``. Writes ``benchmarks/results/render.json``,
``render.md`` and ``render.png`` (quick: ``render_quick.{json,md,png}``, smaller and fewer).

- **Speed**: for each variant (``scalar_rgb``, ``llvm_ad_rgb``, ``cuda_ad_rgb``), in a child
  process of its own (a bad libLLVM aborts the process), ``abrdf_jax.render.render_table`` of
  the reconstructed anisotropic table on the sphere under the environment light: one warm-up
  render (plugin registration, kernel compilation), then the median of ``REPEATS`` renders at
  the stated size and spp. A variant that does not work is listed with the reason. Dr.Jit's
  thread count and the load average (``os.getloadavg``) before and after are stored.
- **Figure**: ``ward-brushed-steel`` (anisotropic, aniso204) and ``nbrdf:gold-paint``
  (isotropic, iso102; the shared MERL fits) sampled and reconstructed with the public API
  (``aj.reconstruct(aj.sample(m, cfg, params), cfg, params)``, recommended configuration),
  rendered beside their dense references on both shapes under both lights with the fastest
  working variant; the ΔE76 of each view is stored beside the figure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from ._loadavg import load_average

RESULTS = Path(__file__).resolve().parent / "results"
VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
REPEATS = 3
#: (material, budget) of the figure, anisotropic first.
MATERIALS = (("ward-brushed-steel", "aniso204"), ("nbrdf:gold-paint", "iso102"))


def reconstruction(name: str, budget: str):
    """``(reference, reconstruction)`` tables of a built-in material (public API only)."""
    import numpy as np

    import abrdf_jax as aj
    from abrdf_jax import materials

    m = materials.get_material(name)
    cfg = aj.Config.recommended(budget=budget)
    params = aj.Params.default(cfg)
    rec = np.asarray(aj.reconstruct(aj.sample(m, cfg, params), cfg, params))
    return materials.dense_table(m), rec


def _child(variant: str, size: int, spp: int, table_file: str) -> None:
    """Time ``render_table`` in ``variant``; print one ``RESULT {json}`` line."""
    import numpy as np

    from abrdf_jax.render import render_table

    table = np.load(table_file)["abrdf"]
    kw = dict(shape="sphere", light="env", size=size, spp=spp, variant=variant)
    t0 = time.perf_counter()
    render_table(table, **kw)
    warm = time.perf_counter() - t0
    times = []
    for k in range(REPEATS):
        t = time.perf_counter()
        img = render_table(table, **kw, seed=k + 1)
        times.append(time.perf_counter() - t)
    import drjit as dr
    import mitsuba as mi

    doc = dict(
        seconds_per_image=statistics.median(times),
        seconds=times,
        warmup_seconds=warm,
        threads=int(dr.thread_count()),
        mitsuba=mi.__version__,
        drjit=dr.__version__,
        libllvm=os.environ.get("DRJIT_LIBLLVM_PATH"),
        finite=bool(np.isfinite(img).all()),
    )
    print("RESULT " + json.dumps(doc))


def time_variant(variant: str, size: int, spp: int, table_file: Path) -> dict:
    """One variant's timing in a child process, or ``{"available": False, "reason": ...}``."""
    from abrdf_jax import InputError
    from abrdf_jax.render import render_table

    try:  # the probe (a tiny render in a child) and the variant's checks, with the reason
        render_table(__import__("numpy").full((81, 81, 3), 0.1), size=8, spp=1, variant=variant)
    except InputError as e:
        return {"available": False, "reason": str(e)}
    load = load_average()
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    argv = [sys.executable, "-m", "benchmarks.render", "--child", variant, str(size), str(spp)]
    proc = subprocess.run(
        [*argv, str(table_file)], env=env, capture_output=True, text=True, timeout=1800
    )
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"available": False, "reason": f"exit status {proc.returncode}: {tail[:200]}"}
    doc = json.loads(lines[-1][len("RESULT ") :])
    return {"available": True, **doc, "load_before": load, "load_after": load_average()}


def _markdown(out: dict) -> str:
    s = out["speed"]
    lines = [
        "# Mitsuba 3 renders (`python -m benchmarks.render`)",
        "",
        f"{out['machine']['date']}, {out['machine']['processor']}, {out['machine']['cpu_count']} "
        f"cores, JAX devices {', '.join(out['machine']['jax_devices'])}.",
        "",
        f"Seconds per image: `abrdf_jax.render.render_table` of the reconstructed "
        f"{MATERIALS[0][0]} table, sphere, env light, {s['size']} x {s['size']} px, {s['spp']} "
        f"spp, median of {REPEATS} after one warm-up render; each variant in its own process.",
        "",
        "| variant | s / image | warm-up s | threads | load before → after | note |",
        "| --- | ---: | ---: | ---: | --- | --- |",
    ]
    for v, r in s["variants"].items():
        if r["available"]:
            load = f"{r['load_before'][0]:.2f} → {r['load_after'][0]:.2f}"
            llvm = v.startswith("llvm") and r.get("libllvm")
            note = f"libLLVM {r['libllvm']}" if llvm else ""
            lines.append(
                f"| {v} | {r['seconds_per_image']:.3g} | {r['warmup_seconds']:.3g} | "
                f"{r['threads']} | {load} | {note} |"
            )
        else:
            lines.append(f"| {v} | — | — | — | — | unavailable: {r['reason']} |")
    f = out["figure"]
    lines += [
        "",
        f"Figure `render.png`: {f['variant']}, {f['size']} x {f['size']} px, {f['spp']} spp, "
        f"lights env and point, rendered in {f['seconds']:.0f} s (load "
        f"{f['load_before'][0]:.2f} → {f['load_after'][0]:.2f}). ΔE76 over the object's pixels, "
        "reconstruction against reference (the table's own ΔE76 over the 81 x 81 pairs beside):",
        "",
        "| material | budget | table ΔE76 | shape | light | mean | 95th pct | max | exposure |",
        "| --- | --- | ---: | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for m in f["materials"]:
        for v in m["views"]:
            lines.append(
                f"| {m['name']} | {m['budget']} | {m['table_de76']:.2f} | {v['shape']} | "
                f"{v['light']} | {v['de76_mean']:.2f} | {v['de76_p95']:.2f} | "
                f"{v['de76_max']:.2f} | {v['exposure']:.3g} |"
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small images, fewer samples")
    ap.add_argument("--child", nargs=4, metavar=("VARIANT", "SIZE", "SPP", "TABLE"))
    args = ap.parse_args(argv)
    if args.child:
        v, size, spp, table = args.child
        _child(v, int(size), int(spp), table)
        return 0
    import tempfile

    import numpy as np

    from abrdf_jax import metrics, render

    from ._common import machine, write_json

    lib = render.llvm_library()  # before Mitsuba starts Dr.Jit (render_table would set it too)
    if lib and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
    size, spp = (32, 4) if args.quick else (64, 16)
    fig_size, fig_spp = (48, 8) if args.quick else (128, 128)
    tables = {name: (budget, *reconstruction(name, budget)) for name, budget in MATERIALS}
    out = {"machine": machine(), "quick": args.quick}
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "rec.npz"
        np.savez(f, abrdf=tables[MATERIALS[0][0]][2])
        timed = {v: time_variant(v, size, spp, f) for v in VARIANTS}
    for v, r in timed.items():
        what = f"{r['seconds_per_image']:.3g} s per image" if r["available"] else r["reason"]
        print(f"{v}: {what}", flush=True)
    out["speed"] = {"size": size, "spp": spp, "repeats": REPEATS, "variants": timed}
    works = [v for v in ("llvm_ad_rgb", "scalar_rgb") if timed[v]["available"]]
    variant = works[0]
    if variant == "scalar_rgb":
        fig_size, fig_spp = size, spp  # scalar is about 100x slower (render.md)
    rows, mats, load, t0 = [], [], load_average(), time.perf_counter()
    for name, (budget, ref, rec) in tables.items():
        views = render.render_views(
            rec, ref, lights=("env", "point"), size=fig_size, spp=fig_spp, variant=variant
        )
        for shape in ("sphere", "cylinder"):
            rows.append((f"{name} ({budget})", [v for v in views if v.shape == shape]))
        errs = [(v, render.view_error(v)) for v in views]
        mats.append(
            dict(
                name=name,
                budget=budget,
                table_de76=float(metrics.delta_e76(rec, ref)),
                views=[
                    dict(
                        shape=v.shape,
                        light=v.light,
                        **{k: x for k, x in e.items() if k != "de76_map"},
                    )
                    for v, e in errs
                ],
            )
        )
        print(f"{name}: rendered {len(views) * 2} images", flush=True)
    stem = "render_quick" if args.quick else "render"
    seconds = time.perf_counter() - t0
    out["figure"] = dict(
        variant=variant, size=fig_size, spp=fig_spp, seconds=seconds, load_before=load,
        load_after=load_average(), materials=mats,
    )  # fmt: skip
    note = (
        f"python -m benchmarks.render: {variant}, {fig_size} x {fig_size} px, {fig_spp} spp, "
        "direct illumination; reconstructions from the protocol's samples (recommended "
        "configuration) beside the dense references"
    )
    render.scene_figure(rows, RESULTS / f"{stem}.png", note=note)
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(_markdown(out))
    print(f"wrote {RESULTS / stem}.{{json,md,png}}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
