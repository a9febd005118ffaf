"""The suite's charts: speed against accuracy (``speed_accuracy.png``) and the compiled operator's
throughput against batch size (``throughput_batch.png``).

Part of the speed/accuracy suite (:mod:`benchmarks.suite`); both draw from a suite payload alone,
so ``python -m benchmarks --replot`` redraws them from the stored JSON.
"""

from __future__ import annotations

from ._suite_run import pareto

GROUP_STYLE = {  # colour of each group on the chart
    "paper": "#1f77b4",
    "recommended": "#d62728",
    "budget": "#9467bd",
    "rule": "#8c564b",
    "kernel": "#e377c2",
    "parameterization": "#7f7f7f",
    "float64": "#17becf",
    "peer: scipy": "#ff7f0e",
    "peer: PCA": "#2ca02c",
    "peer: analytic": "#bcbd22",
    "mean fill": "#000000",
    "tuned": "#ff9896",
    "operator": "#393b79",
    "learned (default prior)": "#e6550d",
    "bivariate": "#00a087",
}


def plot(payload: dict, path=None, dataset: str = "merl-test"):
    """The speed/accuracy chart of a suite payload: time per ABRDF (log) against ΔE76 and LogErr.

    One point per configuration, coloured by group; circles iso (diagonal slices only), triangles
    aniso layouts; the Pareto front of each panel is a dashed step line, its points ringed and
    labelled. Returns the matplotlib figure (saved to ``path`` when given).
    """
    import matplotlib
    import matplotlib.ticker

    if path is not None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [p for p in payload["points"] if p["dataset"] == dataset and "error" not in p]
    fig, axes = plt.subplots(1, 2, figsize=(14, 6), constrained_layout=True)
    cmap = plt.get_cmap("tab20")
    order = list(GROUP_STYLE)
    groups = sorted(
        {p["group"] for p in pts}, key=lambda g: (order.index(g) if g in order else len(order), g)
    )
    colour = {g: GROUP_STYLE.get(g, cmap(i % 20)) for i, g in enumerate(groups)}
    labels = ("mean ΔE76 (lower is better)", "mean LogErr (lower is better)")
    for ax, metric, label in zip(axes, ("de76", "logerr"), labels):
        for g in groups:
            for marker, iso in (("o", True), ("^", False)):
                sel = [p for p in pts if p["group"] == g and (p["budget"] == "iso102") == iso]
                if sel:
                    ax.scatter(
                        [p["seconds_per_abrdf"] for p in sel],
                        [p[metric] for p in sel],
                        c=[colour[g]],
                        marker=marker,
                        s=36,
                        alpha=0.85,
                        label=g
                        if iso or not any(p["group"] == g and p["budget"] == "iso102" for p in pts)
                        else None,
                    )
        front = [next(p for p in pts if p["name"] == n) for n in pareto(pts, metric)]
        xs = [p["seconds_per_abrdf"] for p in front]
        ys = [p[metric] for p in front]
        ax.step(xs, ys, where="post", ls="--", c="0.3", lw=1, label="Pareto front")
        ax.scatter(xs, ys, s=120, facecolors="none", edgecolors="0.2", lw=1.2)
        for i, p in enumerate(front):  # staggered labels: front points often sit close together
            ax.annotate(
                p["name"],
                (p["seconds_per_abrdf"], p[metric]),
                textcoords="offset points",
                xytext=(6, 10 - 11 * (i % 3)),
                fontsize=7,
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        plain = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain)
        ax.tick_params(axis="y", which="minor", labelsize=7)
        ax.set_xlabel("time per ABRDF, batched, after compilation [s] (log)")
        ax.set_ylabel(label + " (log)")
        ax.grid(True, which="both", alpha=0.3)
    n = pts[0]["n_materials"] if pts else 0
    m = payload.get("machine", {})
    fig.suptitle(
        f"Speed against accuracy, {dataset} ({n} materials), {payload.get('mode', '')} run; "
        f"{m.get('cpu_count', '?')} CPUs, JAX {m.get('jax', '?')}; circles iso, triangles aniso layouts",
        fontsize=10,
    )
    axes[1].legend(fontsize=7, loc="upper right", ncol=2)
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def plot_throughput(payload: dict, path=None):
    """ABRDFs per second (log) against batch size (log) of the operator, with the roofline and peers.

    Left: throughput of each preset, the rate the measured square GEMM would give at the
    operator's flops per ABRDF (the roofline), and the scipy peer's rate when in the run. Right:
    XLA's buffer sizes of the compiled apply function per batch size. Returns the figure.
    """
    import matplotlib

    if path is not None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tp = payload["throughput"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5), constrained_layout=True)
    peak = tp["gemm_square"]["gflops"] * 1e9
    for name, pre in tp["presets"].items():
        rows = pre["rows"]
        b = [r["batch"] for r in rows]
        ax.plot(b, [r["abrdfs_per_second"] for r in rows], "o-", label=f"operator, {name} preset")
        mem = [(r["batch"], r["memory"]["total_bytes"] / 2**20) for r in rows if r.get("memory")]
        if mem:
            ax2.plot(*zip(*mem), "o-", label=f"{name} preset (arguments + output + temporaries)")
    first = next(iter(tp["presets"].values()))
    flops_per_abrdf = 2.0 * first["matrix_shape"][0] * first["n_inputs"] * 3
    ax.axhline(
        peak / flops_per_abrdf,
        c="k",
        ls="--",
        lw=1,
        label=f"roofline: square GEMM {tp['gemm_square']['gflops']:.0f} GFLOP/s at this GEMM's flops",
    )
    ax.axhline(
        tp["gemm_same_shape"]["gflops"] * 1e9 / flops_per_abrdf,
        c="0.5",
        ls=":",
        lw=1,
        label="the same-shape GEMM alone (XLA)",
    )
    nb = tp.get("gemm_same_shape_numpy")
    if nb:
        ax.axhline(
            nb["gflops"] * 1e9 / flops_per_abrdf,
            c="0.5",
            ls="-.",
            lw=1,
            label=f"the same-shape GEMM alone (numpy, {nb['blas']})",
        )
    scipy = (tp.get("targets") or {}).get("scipy_abrdfs_per_second")
    if scipy:
        ax.axhline(scipy, c="#ff7f0e", ls="-.", lw=1, label=f"scipy peer ({scipy:.1f} ABRDF/s)")
    ax.axhline(5000, c="#d62728", lw=0.8, alpha=0.6, label="target 5,000 ABRDF/s")
    for a in (ax, ax2):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("batch size (materials per call)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7)
    ax.set_ylabel("ABRDFs per second (iso102 → 81×81×3, float32, after compilation)")
    ax2.set_ylabel("XLA buffers of the compiled call [MiB]")
    m = payload.get("machine", {})
    fig.suptitle(
        f"Compiled operator throughput, {payload.get('mode', '')} run; {m.get('cpu_count', '?')} CPUs, "
        f"JAX {m.get('jax', '?')}; load {payload.get('load_average_before')} → "
        f"{payload.get('load_average_after')}; peak RSS {tp['peak_rss_mb']:.0f} MB",
        fontsize=10,
    )
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig
