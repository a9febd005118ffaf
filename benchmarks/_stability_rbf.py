"""Part 1 of the stability benchmark (:mod:`benchmarks.stability`): RBF conditioning.

The iso102 RBF system for each kernel family in float32 and float64 over kernel widths and λ: the
estimated condition number, whether the plain solve is singular to working precision, NaN in the
tables and ΔE76 with the guard off and on, and how far float32 is from float64.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj

from ._stability_common import (
    de76,
    exact_cond,
    log,
    nonfinite,
    params_for,
    reconstruct,
    sample_stack,
    solve_diag,
)


def conditioning(quick, names, models, refs):
    widths = (0.05, 0.45, 3.0) if quick else (0.05, 0.15, 0.45, 1.0, 2.0, 5.0)
    regs = (0.0, 1e-3)
    models, refs = models[:4], refs[:4]
    kernels = ("gaussian", "thin_plate_spline", "multiquadric") if quick else aj.KERNELS
    rows = []
    for kernel in kernels:
        cfg = aj.Config(kernel=kernel)
        tables = {}
        for dtype in (jnp.float32, jnp.float64):
            dname = np.dtype(dtype).name
            meas = sample_stack(models, cfg, params_for(cfg, dtype))
            for w in widths:
                for reg in regs:
                    p = params_for(cfg, dtype, w, reg)
                    row = dict(kernel=kernel, dtype=dname, width=w, reg=reg)
                    bare = solve_diag(cfg, dtype, w, reg, guard=False)
                    guarded = solve_diag(cfg, dtype, w, reg, guard=True)
                    row.update(
                        cond=bare["cond"],
                        singular=not bare["ok"],
                        guard_reg=guarded["reg"],
                        guard_retries=guarded["retries"],
                        guard_ok=bool(guarded["ok"]),
                        guard_cond=guarded["cond"],
                    )
                    for tag, guard in (("guard", True), ("bare", False)):
                        if not guard and guarded["retries"] == 0:  # the guard kept λ: same solve
                            for key in ("nonfinite", "de76", "max"):
                                row[f"{key}_bare"] = row[f"{key}_guard"]
                            continue
                        rec = reconstruct(cfg, meas, p, guard)
                        row[f"nonfinite_{tag}"] = nonfinite(rec)
                        row[f"de76_{tag}"] = (
                            float(np.nanmean(de76(rec, refs)))
                            if np.isfinite(rec).any()
                            else math.nan
                        )
                        row[f"max_{tag}"] = (
                            float(np.nanmax(np.where(np.isfinite(rec), np.abs(rec), np.nan)))
                            if np.isfinite(rec).any()
                            else math.nan
                        )
                        if guard:
                            tables[(dname, w, reg)] = rec
                    if dname == "float64" and reg == 0.0:
                        row["cond_exact"] = exact_cond(cfg, w, reg)
                    rows.append(row)
            log(f"conditioning {kernel} {dname} done")
        for row in rows:
            if row["kernel"] == kernel:
                t32, t64 = (
                    tables[("float32", row["width"], row["reg"])],
                    tables[("float64", row["width"], row["reg"])],
                )
                scale = np.max(np.abs(t64)) if np.isfinite(t64).all() else math.nan
                row["f32_vs_f64"] = (
                    float(np.max(np.abs(t32 - t64)) / scale)
                    if np.isfinite(t32).all() and scale > 0
                    else math.nan
                )
    return rows


def breaks(rows):
    """Per kernel and dtype: where the plain solve breaks, and what the guard does there."""
    out = []
    for kernel in dict.fromkeys(r["kernel"] for r in rows):
        for dname in ("float32", "float64"):
            rs = [r for r in rows if r["kernel"] == kernel and r["dtype"] == dname]
            if not rs:
                continue
            best = np.nanmin([r["de76_guard"] for r in rs])
            sing = [r for r in rs if r["singular"]]
            nan = [r for r in rs if r["nonfinite_bare"]]
            blow = [r for r in rs if not (r["de76_bare"] <= 2 * best)]  # NaN counts as blow-up
            f32 = [r for r in rs if r.get("f32_vs_f64", 0) > 1e-2]
            fmt = lambda lst: ", ".join(f"w={r['width']:.3g}/λ={r['reg']:g}" for r in lst) or "none"  # noqa: E731
            out.append(
                dict(
                    kernel=kernel,
                    dtype=dname,
                    best_de76=float(best),
                    singular=fmt(sing),
                    nan_bare=fmt(nan),
                    blowup_bare=fmt(blow),
                    blowup_guard=fmt([r for r in rs if not (r["de76_guard"] <= 2 * best)]),
                    nonfinite_guard=sum(r["nonfinite_guard"] for r in rs),
                    retries=sum(r["guard_retries"] for r in rs),
                    guard_not_ok=sum(not r["guard_ok"] for r in rs),
                    f32_ne_f64=fmt(f32) if dname == "float32" else "",
                    max_cond=float(np.nanmax([r["cond"] for r in rs])),
                )
            )
    return out
