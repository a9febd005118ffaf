"""Output of the stability benchmark (:mod:`benchmarks.stability`): the five charts and the markdown report."""

from __future__ import annotations

import math

import numpy as np

from ._common import RESULTS
from ._stability_common import METHODS


def charts(payload, suffix):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = payload["conditioning"]
    kernels = list(dict.fromkeys(r["kernel"] for r in rows))
    paths = []
    # condition vs width (λ = 0, plain solve), both dtypes
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, dname in zip(axes, ("float32", "float64")):
        for k in kernels:
            rs = [r for r in rows if r["kernel"] == k and r["dtype"] == dname and r["reg"] == 0.0]
            ax.loglog([r["width"] for r in rs], [r["cond"] for r in rs], "o-", label=k, ms=3)
        ax.axhline(1 / np.finfo(dname).eps, color="k", ls="--", lw=1)
        ax.text(
            ax.get_xlim()[0],
            1 / np.finfo(dname).eps,
            " 1/ε: guard threshold",
            va="bottom",
            fontsize=8,
        )
        ax.set_title(f"estimated condition, λ = 0, {dname}")
        ax.set_xlabel("kernel width ℓ (radians of the onion coordinates)")
    axes[0].set_ylabel("κ₁ (Hager estimate)")
    axes[1].legend(fontsize=7)
    paths.append(_save(fig, f"stability_condition{suffix}.png"))
    # error vs width: guard off / on, f32 and f64, λ = 0
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, dname in zip(axes, ("float32", "float64")):
        for i, k in enumerate(kernels):
            rs = [r for r in rows if r["kernel"] == k and r["dtype"] == dname and r["reg"] == 0.0]
            col = f"C{i}"
            ax.semilogx(
                [r["width"] for r in rs], [r["de76_bare"] for r in rs], "x--", color=col, ms=4
            )
            ax.semilogx(
                [r["width"] for r in rs],
                [r["de76_guard"] for r in rs],
                "o-",
                color=col,
                ms=3,
                label=k,
            )
        ax.set_yscale("log")
        ax.set_title(
            f"ΔE76 vs width, λ = 0, {dname}\n(solid: guard on; dashed: off; gaps: NaN)", fontsize=10
        )
        ax.set_xlabel("kernel width ℓ")
    axes[0].set_ylabel("mean ΔE76")
    axes[1].legend(fontsize=7)
    paths.append(_save(fig, f"stability_width{suffix}.png"))
    curves = payload["data_edges"]["curves"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name in METHODS:
        axes[0].plot(curves["noise"]["x"], curves["noise"][name], "o-", label=name, ms=3)
        axes[1].plot(
            curves["few_samples"]["x"], curves["few_samples"][name], "o-", label=name, ms=3
        )
    axes[0].set_xlabel("multiplicative noise σ")
    axes[0].set_title("ΔE76 vs measurement noise")
    axes[1].set_xlabel("samples kept per slice (of 24-26)")
    axes[1].set_title("ΔE76 vs samples per slice")
    axes[1].invert_xaxis()
    for ax in axes:
        ax.set_ylabel("mean ΔE76")
    axes[0].legend(fontsize=7)
    paths.append(_save(fig, f"stability_noise{suffix}.png"))
    an = payload["anisotropy"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name in METHODS:
        axes[0].plot(an["strength"]["x"], an["strength"][name], "o-", label=name, ms=3)
        axes[1].plot(an["rotation"]["x"], an["rotation"][name], "o-", label=name, ms=3)
    axes[0].set_xlabel("anisotropy α_y / α_x (Ward, axis along x)")
    axes[0].set_title("ΔE76 vs anisotropy strength")
    axes[1].set_xlabel("axis rotation (degrees; α_y/α_x = 5)")
    axes[1].set_title("ΔE76 vs anisotropy axis rotation")
    for ax in axes:
        ax.set_ylabel("ΔE76")
    axes[0].legend(fontsize=7)
    paths.append(_save(fig, f"stability_anisotropy{suffix}.png"))
    e4 = payload["eq4"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for rule in ("filip2012", "average", "crossing", "log", "iso102 (diagonal)"):
        ax.semilogx(e4["range_diag"], e4[rule], "o-", label=rule, ms=3)
    ax.set_xlabel("dynamic range of the diagonal slice at 30/30 (max/min)")
    ax.set_ylabel("ΔE76")
    ax.set_title("subspace rules vs a dominating specular slice (aniso204)")
    ax.legend(fontsize=7)
    paths.append(_save(fig, f"stability_eq4{suffix}.png"))
    return paths


def _save(fig, name):
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = RESULTS / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path.relative_to(RESULTS.parent.parent))


def g(v, f=".3g"):
    return "NaN" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, f)


def markdown(payload) -> str:
    out = [
        f"# Stability benchmark ({'quick' if payload['quick'] else 'full'} run)",
        "",
        f"`python -m benchmarks.stability{' --quick' if payload['quick'] else ''}`, "
        f"{payload['seconds']:.0f} s, {payload['machine']['date']}, {payload['machine']['jax_devices']}, "
        f"materials: {', '.join(payload['materials'])}",
        "",
        "## RBF conditioning: where the plain solve breaks (iso102 system, 1296 centres)",
        "",
        "| kernel | dtype | max κ₁ | singular (κ ≥ 1/ε) | NaN, guard off | ΔE > 2× best, guard off | "
        "ΔE > 2× best, guard on | best ΔE | guard retries / not ok | f32 ≠ f64 (>1%) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for b in payload["breaks"]:
        out.append(
            f"| {b['kernel']} | {b['dtype']} | {g(b['max_cond'])} | {b['singular']} | {b['nan_bare']} | "
            f"{b['blowup_bare']} | {b['blowup_guard']} | {g(b['best_de76'], '.2f')} | "
            f"{b['retries']} / {b['guard_not_ok']} | {b['f32_ne_f64']} |"
        )
    est = [
        (r["cond"], r["cond_exact"])
        for r in payload["conditioning"]
        if "cond_exact" in r and np.isfinite(r["cond_exact"]) and r["cond_exact"] < 1e15
    ]
    if est:
        ratio = np.array([e / c for c, e in est])
        out += [
            "",
            f"Hager estimate vs exact κ₁ (float64, κ < 1e15, {len(est)} systems): exact/estimate "
            f"median {np.median(ratio):.3g}, max {np.max(ratio):.3g}.",
        ]
    out += [
        "",
        "## Data edges (float32, package defaults of each method)",
        "",
        "Materials: iso102 columns the isotropic set above; aniso204 columns lambert-clay, ggx-plastic "
        "and ward-brushed-steel. Errors are means over the batch.",
        "",
        "| case | " + " | ".join(METHODS) + " |",
        "|---|" + "---|" * len(METHODS),
    ]
    cases = payload["data_edges"]["cases"]
    for case in dict.fromkeys(c["case"] for c in cases):
        cells = []
        for name in METHODS:
            c = next((c for c in cases if c["case"] == case and c["method"] == name), None)
            if c is None:
                cells.append("n/a")
            elif c["nonfinite"]:
                cells.append(f"**{c['nonfinite']} non-finite**")
            else:
                cells.append(g(c.get("error")) + (f" (min {g(c['min'])})" if c["min"] < 0 else ""))
        note = next(c["note"] for c in cases if c["case"] == case)
        out.append(f"| {case} ({note}) | " + " | ".join(cells) + " |")
    curves = payload["data_edges"]["curves"]
    for key, label in (("noise", "noise σ"), ("few_samples", "samples per slice")):
        xs = curves[key]["x"]
        out += [
            "",
            f"ΔE76 vs {label}:",
            "",
            "| method | " + " | ".join(g(x) for x in xs) + " |",
            "|---|" + "---|" * len(xs),
        ]
        out += [
            f"| {n} | " + " | ".join(g(v, ".2f") for v in curves[key][n]) + " |" for n in METHODS
        ]
    an = payload["anisotropy"]
    for key, label in (("strength", "anisotropy α_y/α_x"), ("rotation", "axis rotation (deg)")):
        xs = an[key]["x"]
        out += [
            "",
            f"ΔE76 vs {label} (Ward):",
            "",
            "| method | " + " | ".join(g(x) for x in xs) + " |",
            "|---|" + "---|" * len(xs),
        ]
        out += [f"| {n} | " + " | ".join(g(v, ".2f") for v in an[key][n]) + " |" for n in METHODS]
    e4 = payload["eq4"]
    out += [
        "",
        "Eq. (4) and the other subspace rules (aniso204, recommended RBF), GGX α_x = a, α_y = 3a:",
        "",
        "| a | diagonal-slice range | axial-slice range | "
        + " | ".join(("filip2012", "average", "crossing", "log", "iso102 (diagonal)"))
        + " |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, a in enumerate(e4["x_alpha"]):
        out.append(
            f"| {a:g} | {g(e4['range_diag'][i])} | {g(e4['range_axial'][i])} | "
            + " | ".join(
                g(e4[r][i], ".2f")
                for r in ("filip2012", "average", "crossing", "log", "iso102 (diagonal)")
            )
            + " |"
        )
    out += ["", "Charts: " + ", ".join(f"`{p}`" for p in payload["charts"]), ""]
    return "\n".join(out)
