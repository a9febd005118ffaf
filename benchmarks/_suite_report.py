"""The suite's tables: the markdown table and summary of a run (``suite.md``), and the files it writes.

Part of the speed/accuracy suite (:mod:`benchmarks.suite`).
"""

from __future__ import annotations

from pathlib import Path

from ._suite_charts import plot, plot_throughput
from ._suite_run import pareto


def table(payload: dict, dataset: str = "merl-test") -> str:
    """A markdown table of the points of ``dataset``, fastest first, Pareto points marked."""
    pts = sorted(
        (p for p in payload["points"] if p.get("dataset") == dataset and "error" not in p),
        key=lambda p: p["seconds_per_abrdf"],
    )
    lines = [
        "| configuration | group | samples | dtype | ms per ABRDF | ΔE76 | LogErr | ΔE2000 | PSNR dB | Pareto |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in pts:
        front = (
            "/".join(
                m for m, key in (("ΔE", "pareto_de76"), ("Log", "pareto_logerr")) if p.get(key)
            )
            or ""
        )
        lines.append(
            f"| {p['name']} | {p['group']} | {p['n_samples']} | {p['dtype']} "
            f"| {p['seconds_per_abrdf'] * 1e3:.3g} "
            f"| {p['de76']:.2f} | {p['logerr']:.3f} | {p['de2000']:.2f} | {p['psnr']:.2f} | {front} |"
        )
    return "\n".join(lines)


def summary(payload: dict, dataset: str = "merl-test") -> list[str]:
    """Where each method wins, read off the points (sentences with the figures)."""
    pts = [p for p in payload["points"] if p.get("dataset") == dataset and "error" not in p]
    if not pts:
        return []
    ms = lambda p: f"{p['seconds_per_abrdf'] * 1e3:.3g} ms"  # noqa: E731
    out = []
    for metric, label in (("de76", "ΔE76"), ("logerr", "LogErr")):
        best = min(pts, key=lambda p: p[metric])
        fast = min(pts, key=lambda p: p["seconds_per_abrdf"])
        front = [next(p for p in pts if p["name"] == n) for n in pareto(pts, metric)]
        out.append(
            f"{label}: most accurate {best['name']} ({best[metric]:.3g}, {ms(best)} per ABRDF); fastest "
            f"{fast['name']} ({fast[metric]:.3g}, {ms(fast)}); Pareto front: "
            + ", ".join(f"{p['name']} ({p[metric]:.3g}, {ms(p)})" for p in front)
            + "."
        )
    return out


def write_outputs(payload: dict, out: Path, plots: bool = True) -> None:
    """Write the markdown table ``suite{_mode}.md`` and the two charts of a suite payload to ``out``."""
    mode = payload["mode"]
    suffix = "" if mode == "full" else f"_{mode}"
    ok = [p for p in payload["points"] if "error" not in p]
    tp = payload.get("throughput")
    if plots and ok:
        plot(payload, out / f"speed_accuracy{suffix}.png")
    if plots and tp:
        plot_throughput(payload, out / f"throughput_batch{suffix}.png")
    command = "python -m benchmarks" + ("" if mode == "full" else f" --{mode}")
    m = payload["machine"]
    text = [
        f"# Speed against accuracy ({mode} run, `{command}`)",
        "",
        f"{m['date']}, {m['platform']}, {payload['threads']['cpu_count']} CPUs, JAX {m['jax']} on "
        f"{', '.join(m['jax_devices'])}; load average (1, 5, 15 min) before {payload['load_average_before']}, "
        f"after {payload['load_average_after']}; {payload['seconds']:.0f} s in all.",
        "",
    ]
    for u in payload.get("updates", []):
        text += [
            f"Updated {u['date']} (load {u['load_average_before']} → {u['load_average_after']}): "
            + ", ".join(u["entries"])
            + ".",
            "",
        ]
    failed = [p for p in payload["points"] if "error" in p]
    if failed:
        text += [
            "Failed configurations: "
            + "; ".join(f"{p['name']} [{p['dataset']}]: {p['error']}" for p in failed),
            "",
        ]
    for ds in sorted(payload["pareto"], key=lambda d: (d != "merl-test", d)):
        text += [f"## {ds}", "", table(payload, ds), "", *summary(payload, ds), ""]
    if tp:
        from .throughput import table as tp_table

        text += [
            "## Throughput of the compiled operator (iso102 → 81×81×3, float32)",
            "",
            tp_table(tp),
            "",
            *[f"- {line}" for line in tp["targets"]["lines"]],
            "",
        ]
    (out / f"suite{suffix}.md").write_text("\n".join(text))
