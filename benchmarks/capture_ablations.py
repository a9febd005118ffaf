"""Two ablations behind docs/captures.md, on MERL test materials (iso captures, recommended preset).

- ``density``: ΔE76 against samples per slice (protocol, 50, 100, 1000) with the dense layout of
  ``group_slices`` (24 centre azimuths per ring, the default) and without it
  (``centre_azimuths=None``: the UBO centres); both with the configuration's spike cap
  (``Config.spike_cap``; ``python -m benchmarks.spike_cap`` shows it); per material in the JSON.
- ``noise``: relative value noise 0, 2, 5, 10 % against the RBF regularisation (the tuned λ and
  larger ones), and the capture's noise estimate (``abrdf_jax.select.estimate_noise``, log units):
  a larger λ never helped. What the noise sets instead, the slice smoothing
  (``Config.slice_smoothing``), is measured by ``python -m benchmarks.noise_smoothing``.
- ``jitter``: 0.5° angle jitter with several seeds per material: how much of the jitter cost is
  where the samples happen to fall (the ratio of mean ΔE76 to the protocol's, per seed).

Run: ``python -m benchmarks.capture_ablations [--materials N]``; writes
``benchmarks/results/capture_ablations.json`` and prints markdown tables.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics, select

from ._common import load_average, machine, write_json

NOISE = (0.0, 0.02, 0.05, 0.10)
REGS = (None, 1e-2, 1e-1)  # None: the preset's tuned λ


DENSITIES = (None, 50, 100, 1000)  # None: the protocol counts


def _density(names, cfg):
    """ΔE76 per material for each density, with the dense layout (default) and the UBO one."""
    out = {}
    for i, n in enumerate(names):
        m = materials.get_material("nbrdf:" + n)
        ref = materials.dense_table(m)
        for per in DENSITIES:
            s = aj.simulate_capture(m, budget="iso102", seed=i, per_slice=per)
            for layout, az in (("default", "auto"), ("ubo", None)):
                meas, rep = aj.group_slices(s, centre_azimuths=az)
                p = aj.Params.default(cfg, alpha_deg=rep["alpha_deg"])
                de = float(metrics.evaluate(aj.reconstruct(meas, cfg, p), ref)["de76"])
                out.setdefault(f"{per or 'protocol'}/{layout}", {})[n] = de
    base = np.mean(list(out["protocol/default"].values()))
    lines = [
        "| per slice | UBO centres | default (dense: 24 azimuths) |",
        "|---|---|---|",
    ]
    for per in DENSITIES:
        k = per or "protocol"
        ubo, dflt = (np.mean(list(out[f"{k}/{lay}"].values())) for lay in ("ubo", "default"))
        lines.append(f"| {k} | {ubo:.3f} ({ubo / base:.2f}x) | {dflt:.3f} ({dflt / base:.2f}x) |")
    print("\n".join(lines))
    return out, "\n".join(lines)


JITTER_SEEDS = 4


def _jitter(names, cfg):
    """Mean ΔE76 ratio (jitter 0.5° / protocol) for each of ``JITTER_SEEDS`` seeds."""
    base, per_seed = [], {k: [] for k in range(JITTER_SEEDS)}
    for i, n in enumerate(names):
        m = materials.get_material("nbrdf:" + n)
        ref = materials.dense_table(m)
        base.append(
            float(
                metrics.evaluate(aj.reconstruct(aj.simulate_capture(m, budget="iso102"), cfg), ref)[
                    "de76"
                ]
            )
        )
        for k in per_seed:
            s = aj.simulate_capture(m, budget="iso102", jitter_deg=0.5, seed=1000 * k + i)
            per_seed[k].append(float(metrics.evaluate(aj.reconstruct(s, cfg), ref)["de76"]))
    b = np.asarray(base)
    ratios = {k: float(np.mean(v) / b.mean()) for k, v in per_seed.items()}
    medians = {k: float(np.median(np.asarray(v) / b)) for k, v in per_seed.items()}
    lines = ["| seed | mean ratio | median ratio per material |", "|---|---|---|"]
    lines += [f"| {k} | {ratios[k]:.3f} | {medians[k]:.3f} |" for k in per_seed]
    print("\n".join(lines))
    return dict(
        protocol=dict(zip(names, base)), per_seed=per_seed, mean_ratio=ratios, median_ratio=medians
    ), "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--materials", type=int, default=10, help="MERL test materials (every k-th)")
    ap.add_argument("--per-slice", type=int, default=None, help="noise part: samples per slice")
    args = ap.parse_args(argv)
    load0, t0 = load_average(), time.perf_counter()
    test = materials.merl_split("test")
    names = test[:: max(1, len(test) // args.materials)][: args.materials]
    cfg = aj.preset("recommended", "iso102")
    jitter, jitter_table = _jitter(names, cfg)
    density, density_table = _density(names, cfg)
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
        density=density,
        density_table=density_table,
        jitter=jitter,
        jitter_table=jitter_table,
        machine=machine(),
        load_average_before=load0,
        load_average_after=load_average(),
        seconds=time.perf_counter() - t0,
        command="python -m benchmarks.capture_ablations " + " ".join(argv or []),
        materials=names,
        per_slice=args.per_slice,
        results=[
            dict(noise=k[0], reg=tuned if k[1] is None else k[1], tuned=k[1] is None, **v)
            for k, v in rows.items()
        ],
        noise_table="\n".join(lines),
    )
    print(f"wrote {write_json('capture_ablations.json', payload)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
