"""Noise against smoothing: does a noise-set RBF regularisation pay on noisy captures?

For MERL test materials (iso captures, ``abrdf_jax.simulate_capture`` with relative value noise
0, 2, 5, 10 %), the recommended reconstruction at its tuned λ and at larger ones, ΔE76 against the
dense truth, and the capture's noise estimate (``abrdf_jax.select.estimate_noise``, log units)
beside the true level. Run: ``python -m benchmarks.capture_noise [--materials N] [--per-slice N]``;
writes ``benchmarks/results/capture_noise.json`` and prints a markdown table.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics, select

from ._common import machine, write_json

NOISE = (0.0, 0.02, 0.05, 0.10)
REGS = (None, 1e-2, 1e-1)  # None: the preset's tuned λ


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--materials", type=int, default=10, help="MERL test materials (every k-th)")
    ap.add_argument("--per-slice", type=int, default=None, help="samples per slice (protocol)")
    args = ap.parse_args(argv)
    load0, t0 = os.getloadavg(), time.perf_counter()
    test = materials.merl_split("test")
    names = test[:: max(1, len(test) // args.materials)][: args.materials]
    cfg = aj.preset("recommended", "iso102")
    rows = {}
    for i, n in enumerate(names):
        m = materials.get_material("nbrdf:" + n)
        ref = materials.dense_table(m)
        for noise in NOISE:
            s = aj.simulate_capture(
                m, budget="iso102", noise=noise, seed=i, per_slice=args.per_slice
            )
            meas, rep = aj.group_slices(s)
            sigma = float(select.estimate_noise(meas, slices="all"))
            p0 = aj.Params.default(cfg, alpha_deg=rep["alpha_deg"])
            for reg in REGS:
                p = p0 if reg is None else aj.Params(p0.alpha, p0.widths, np.float32(reg))
                de = float(metrics.evaluate(aj.reconstruct(meas, cfg, p), ref)["de76"])
                r = rows.setdefault((noise, reg), dict(de76=[], sigma=[]))
                r["de76"].append(de)
                r["sigma"].append(sigma)
    tuned = float(aj.Params.default(cfg).reg)
    lines = [
        "| noise | estimate (log, median) | "
        + " | ".join(
            f"ΔE76 λ={tuned if r is None else r:g}" + (" (tuned)" if r is None else "")
            for r in REGS
        )
        + " |",
        "|---|---|" + "---|" * len(REGS),
    ]
    for noise in NOISE:
        est = np.median(rows[(noise, None)]["sigma"])
        des = [np.mean(rows[(noise, r)]["de76"]) for r in REGS]
        lines.append(
            f"| {100 * noise:g} % | {est:.4f} | " + " | ".join(f"{d:.3f}" for d in des) + " |"
        )
    print("\n".join(lines))
    payload = dict(
        machine=machine(),
        load_average_before=load0,
        load_average_after=os.getloadavg(),
        seconds=time.perf_counter() - t0,
        command="python -m benchmarks.capture_noise " + " ".join(argv or []),
        materials=names,
        per_slice=args.per_slice,
        results=[
            dict(noise=k[0], reg=tuned if k[1] is None else k[1], tuned=k[1] is None, **v)
            for k, v in rows.items()
        ],
        table="\n".join(lines),
    )
    print(f"wrote {write_json('capture_noise.json', payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
