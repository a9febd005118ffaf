"""Charts and the markdown table of ``python -m benchmarks.btf`` (see benchmarks/btf.py)."""

from __future__ import annotations

from pathlib import Path

from ._btf_formats import markdown_rows


def scaling_chart(path: Path, sizes, size_times, devices, device_times, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullLocator

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    texels = [s * s for s in sizes]
    a.plot(texels, size_times, "o-", label="measured (warm)")
    a.plot(
        texels,
        [size_times[-1] * t / texels[-1] for t in texels],
        "--",
        color="grey",
        label="linear in texels",
    )
    a.set_xscale("log")
    a.set_yscale("log")
    a.set_xlabel("texels")
    a.set_ylabel("seconds (reconstruct_btf, float16 store)")
    a.xaxis.set_minor_locator(
        NullLocator()
    )  # else the log axis labels its minor ticks over the sizes
    a.set_xticks(texels)
    a.set_xticklabels([f"{s}²" for s in sizes])
    a.legend()
    a.set_title("time against texel count")
    b.plot(devices, device_times, "o-")
    b.set_xscale("log", base=2)
    b.xaxis.set_minor_locator(NullLocator())
    b.set_xticks(devices)
    b.set_xticklabels([str(d) for d in devices])
    b.set_xlabel("simulated CPU devices (XLA_FLAGS), same 2 cores")
    b.set_ylabel("seconds (warm)")
    b.set_ylim(bottom=0)
    b.set_title("time against device count")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def checksum_rows(c: dict | None) -> list[str]:
    """The store checksums' rows of the "beside it" table (runs before 2026-12-07: none)."""
    if not c:
        return []
    return [
        f"| store checksum of one chunk ({c['megabytes']:.0f} MB), {name}"
        f"{' (written)' if name == c['written'] else ' (older stores, verified)'} | {ms:.1f} ms |"
        for name, ms in c["ms_per_chunk"].items()
    ]


def markdown(out: dict, suffix: str) -> str:
    """The results as markdown tables (``btf.md``), every figure from ``out`` (the JSON)."""
    m, h = out["machine"], out["headline"]
    op, roof, single = out["operator_in_memory"], out["roofline_gflops"], out["single_material"]
    lines = [
        f"# Whole-BTF benchmark{' (quick)' if out['quick'] else ''}",
        "",
        f"`python -m benchmarks.btf{' --quick' if out['quick'] else ''}`, {m['date']}, {m['platform']}, "
        f"{m['cpu_count']} CPU cores, JAX {m['jax']} on {', '.join(m['jax_devices'])}, float32 compute, "
        f"float16 store, chunks of {out['chunk']} texels, seed {out['seed']}; load average (1 min) "
        f"{out['load_average_start'][0]:.1f} at the start, {out['load_average_end'][0]:.1f} at the end. "
        f"{out['note']}",
        "",
        "| texels | samples/texel | output | cold (compile incl.) | warm | peak RSS | texels/s (warm) | backend |",
        "|---|---|---|---|---|---|---|---|",
        f"| {h['size']}² = {h['texels']} | {h['samples_per_texel']} | 81×81×3 {h['store_dtype']}, "
        f"{h['store_bytes'] / 2**30:.2f} GiB | {h['seconds_cold']:.1f} s | {h['seconds_warm']:.1f} s | "
        f"{h['peak_rss_gib']:.2f} GiB | {h['texels_per_second_warm']:.0f} | {h['backend']} |",
        "",
        f"Target: {h['target']}.",
        "",
    ]
    if len(h.get("rounds", ())) > 1:
        pairs = ", ".join(f"{r['cold']:.1f} / {r['warm']:.1f} s" for r in h["rounds"])
        lines += [
            f"{len(h['rounds'])} fresh processes (cold / warm): {pairs}; the table gives the "
            "round of median cold time and the median warm time.",
            "",
        ]
    if h.get("glibc_thresholds"):
        g = h["glibc_thresholds"]
        pairs = ", ".join(f"{r['cold']:.1f} / {r['warm']:.1f} s" for r in g["rounds"])
        lines += [
            "The same rounds with glibc's own allocator thresholds, interleaved with those above "
            "(each chunk's output then mapped and faulted in anew; `abrdf_jax.cli._malloc`): "
            f"{pairs}; peak RSS {g['peak_rss_gib']:.2f} GiB against {h['peak_rss_gib']:.2f} GiB.",
            "",
        ]
    if h.get("split"):
        lines += [
            "| where the time goes (busy seconds; read, compute and write overlap) | build | read "
            "| compute | write (summed over the writer threads) | wall |",
            "|---|---|---|---|---|---|",
        ]
        for run in ("cold", "warm"):
            sp, wall = h["split"][run], h[f"seconds_{run}"]
            cells = " | ".join("–" if sp.get(k) is None else f"{sp[k]:.1f} s" for k in sp)
            lines.append(f"| {run} | {cells} | {wall:.1f} s |")
        lines.append("")
    if out.get("store_formats"):
        lines += [*markdown_rows(out["store_formats"], out["chunk"]), ""]
    lines += [
        "| beside it (same run) | figure |",
        "|---|---|",
        f"| single material, `abrdf_jax.reconstruct` (recommended, aniso204), after compilation | "
        f"{single['abrdfs_per_second']:.1f} ABRDF/s |",
        f"| BTF, whole path (read, reconstruct, write), warm | {h['texels_per_second_warm']:.0f} texels/s "
        f"({h['vs_single_material']:.0f}× the single material) |",
        f"| BTF chunk map in memory (one chunk of {op['texels']}, no I/O, as `ShardedRunner` runs it), {op['backend']} | "
        f"{op['texels_per_second']:.0f} texels/s, {op['gflops']:.1f} GFLOP/s"
        + (
            f" (dense-equivalent; {op['executed_gflops']:.1f} executed through its rank-"
            f"{op['low_rank']} factors)"
            if op.get("low_rank")
            else ""
        )
        + " |",
        f"| float32 GEMM roofline, operator shape {op['gemm_shape']} | {roof['operator_shape']:.1f} GFLOP/s "
        f"(chunk map reaches {100 * op['fraction_of_roofline']:.0f} %) |",
        f"| float32 GEMM, 2048³ | {roof['square_2048']:.1f} GFLOP/s |",
        *checksum_rows(out.get("checksums")),
        "",
        "| texels | cold | warm | peak RSS |",
        "|---|---|---|---|",
    ]
    for s, r in out["size_scaling"].items():
        lines.append(
            f"| {s}² | {r['seconds_cold']:.1f} s | {r['seconds_warm']:.2f} s | {r['peak_rss_gib']:.2f} GiB |"
        )
    ds = out["device_scaling"]
    lines += [
        "",
        f"| simulated CPU devices ({ds['size']}² texels, same cores) | cold | warm |",
        "|---|---|---|",
    ]
    for d, r in ds["runs"].items():
        lines.append(f"| {d} | {r['seconds_cold']:.1f} s | {r['seconds_warm']:.2f} s |")
    if "exr_export" in out:
        e = out["exr_export"]
        lines += [
            "",
            f"EXR export (timed apart): {e['images']} images of {h['size']}×{h['size']} half RGB, "
            f"{e['seconds']:.1f} s, {e['bytes'] / 2**20:.0f} MiB.",
        ]
    a = out["accuracy"]
    lines += [
        "",
        f"| accuracy per texel ({a['size']}², vs procedural ground truth) | mean | median | p95 |",
        "|---|---|---|---|",
    ]
    for key, name in (
        ("de76", "ΔE76, ours"),
        ("mean_fill_de76", "ΔE76, mean fill"),
        ("logerr", "LogErr, ours"),
        ("mean_fill_logerr", "LogErr, mean fill"),
    ):
        v = a[key]
        lines.append(f"| {name} | {v['mean']:.3f} | {v['median']:.3f} | {v['p95']:.3f} |")
    lines += [
        "",
        f"Ours better than mean fill on {100 * a['fraction_better_than_mean_fill']:.0f} % of texels. "
        f"Charts: `btf_scaling{suffix}.png`, `btf_error_map{suffix}.png`.",
        "",
    ]
    cc = out.get("config_comparison")
    if cc:
        lines += [
            "",
            f"| configuration ({cc['size']}², seed {cc['seed']}, where the default was chosen) | mean ΔE76 "
            "| mean LogErr |",
            "|---|---|---|",
        ]
        lines += [f"| {k} | {v['de76']:.2f} | {v['logerr']:.3f} |" for k, v in cc["rows"].items()]
    lines.append("")
    return "\n".join(lines)
