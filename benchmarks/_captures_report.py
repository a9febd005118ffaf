"""Output of :mod:`benchmarks.captures`: the markdown tables, the PASS/FAIL list and the charts."""

from __future__ import annotations

from pathlib import Path

from ._captures_kinds import KINDS, protocol_pair_cells


def _f(result: dict, key: str, fmt: str = ".2f") -> str:
    return "n/a" if "n/a" in result else format(result[key], fmt)


def _samples(res: dict) -> str:
    n = list(res["n_samples"].values())
    return f"{min(n)}" if min(n) == max(n) else f"{min(n)}–{max(n)}"


def markdown(payload: dict) -> str:
    quick = payload["mode"] == "quick"
    out = [
        f"# Real captures ({payload['mode']} run)",
        "",
        f"`{payload['commands']['benchmark']}`; each capture kind of a set is one folder call "
        f"`{payload['commands']['reconstruct']}` (default `--model auto`). ΔE76 / LogErr against "
        "the dense truth: mean (median) over materials. scipy: the scipy peer, paper config, where "
        "it runs; fill: mean fill. Load average before/after: "
        f"{payload['load_average_before']} / {payload['load_average_after']}; "
        f"{payload['seconds']:.0f} s in all.",
    ]
    for set_name, block in payload["sets"].items():
        out += [
            "",
            f"## {set_name}: {block['what']} ({len(block['materials'])} materials, "
            f"{block['budget']})",
            "",
            "| capture | samples | exit | s | warnings | ΔE76 | LogErr | scipy ΔE76 | scipy LogErr "
            "| fill ΔE76 | fill LogErr |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        notes = []
        for k, r in block["kinds"].items():
            p, s, f, c = r["package"], r["scipy"], r["mean_fill"], r["cli"]
            de = "n/a" if "n/a" in p else f"{p['de76']:.2f} ({p['de76_median']:.2f})"
            le = "n/a" if "n/a" in p else f"{p['logerr']:.3f} ({p['logerr_median']:.3f})"
            out.append(
                f"| {k}: {r['what']} | {_samples(r)} | {c['exit_code']} | {c['seconds']:.0f} | "
                f"{c['warnings']} | {de} | {le} | {_f(s, 'de76')} | {_f(s, 'logerr', '.3f')} | "
                f"{_f(f, 'de76')} | {_f(f, 'logerr', '.3f')} |"
            )
            for who, res in (("package", p), ("scipy", s)):
                if "n/a" in res:
                    notes.append(f"- {k}, {who}: n/a: {res['n/a'][:300]}")
        if notes:
            out += ["", *notes]
        out += ["", *_where(block["kinds"])]
    out += ["", "## Targets (issue 12)", "", "| target | set | kind | value | limit | result |"]
    out.append("|---|---|---|---|---|---|")
    for t in payload["targets"]:
        v = t["value"]
        v = "n/a" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v))
        if t.get("failed"):
            v += " failed: " + ", ".join(t["failed"])
        limit = f"{'<' if t.get('strict') else '<='} {t['limit']:g}"
        if "statistic" in t:
            limit = f"{t['statistic']} ratio {limit}"
        out.append(
            f"| {t['target']} | {t['set']} | {t['kind']} | {v} | {limit} | "
            f"{'PASS' if t['pass'] else 'FAIL'} |"
        )
    if quick:
        out += ["", "Quick run: a smoke test of the harness, not figures to quote."]
    return "\n".join(out) + "\n"


def _where(kinds: dict) -> list[str]:
    """The package's mean ΔE76 at the protocol's pairs and elsewhere, and the bound it sets."""
    share = float(protocol_pair_cells().mean())
    out = [
        f"Where the package's error lies: mean ΔE76 over the cells at the protocol's four "
        f"elevation pairs (θi, θv ∈ {{30°, 75°}}: {share:.0%} of the 81 × 81 cells, the only ones "
        f"a capture at those pairs measures) and over the other {1 - share:.0%} (interpolated "
        "across elevation):",
        "",
        "| capture | at the protocol's pairs | elsewhere | all cells |",
        "|---|---|---|---|",
    ]
    for k, r in kinds.items():
        p = r["package"]
        if "n/a" in p:
            continue
        out.append(
            f"| {k} | {p['de76_protocol_pairs']:.2f} | {p['de76_elsewhere']:.2f} | "
            f"{p['de76']:.2f} |"
        )
    base = kinds.get("protocol", {}).get("package", {})
    if "de76_elsewhere" in base and base["de76"] > 0:
        bound = (1 - share) * base["de76_elsewhere"] / base["de76"]
        out += [
            "",
            "Denser slices at the same pairs add samples only at the first column's cells: "
            f"were its error 0 and the rest unchanged, the mean would be {bound:.3f} of the "
            "protocol capture's: the ratio denser slices reach unless they also improve the "
            "interpolation elsewhere.",
        ]
    return out


def pass_fail_lines(payload: dict) -> list[str]:
    """One ``PASS``/``FAIL`` line per target, for the console."""
    out = []
    for t in payload["targets"]:
        v = "" if t["value"] is None else f"  ({t['value']:.3g})"
        if t.get("failed"):
            v += " failed: " + ", ".join(t["failed"])
        out.append(
            f"{'PASS' if t['pass'] else 'FAIL'}  {t['set']:5s} {t['kind']:12s} {t['target']}{v}"
        )
    return out


METHODS = (
    ("package", "abrdf_jax CLI", "o-"),
    ("scipy", "scipy peer", "s--"),
    ("mean_fill", "mean fill", "^:"),
)


#: The package's ΔE76 split by cells (``benchmarks.captures.SPLIT``) in the density chart.
SPLIT_LINES = (
    ("de76_protocol_pairs", "abrdf_jax CLI, at the protocol's pairs", "v--"),
    ("de76_elsewhere", "abrdf_jax CLI, elsewhere", "^:"),
)


def _series(kinds: dict, names: list[str], method: str, metric: str = "de76"):
    xs, ys = [], []
    for k, x in names:
        r = kinds.get(k)
        if r is not None and "n/a" not in r[method]:
            xs.append(x)
            ys.append(r[method][metric])
    return xs, ys


def charts(payload: dict, folder: Path, suffix: str) -> list[str]:
    """``captures_density{suffix}.png`` and ``captures_noise{suffix}.png`` in ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = payload["sets"]
    paths = []
    proto_n = 25.5  # the protocol's mean count per slice (25, 25, 26, 26)
    fig, axes = plt.subplots(2, len(sets), figsize=(5.5 * len(sets), 7), squeeze=False)
    for j, (set_name, block) in enumerate(sets.items()):
        kinds = block["kinds"]
        names = [("protocol", proto_n)] + [(k, v.x) for k, v in KINDS.items() if v.group == "dense"]
        for i, metric in enumerate(("de76", "logerr")):
            ax = axes[i, j]
            for method, label, style in METHODS:
                xs, ys = _series(kinds, names, method, metric)
                if xs:
                    ax.plot(xs, ys, style, label=label, ms=4)
            for key, label, style in SPLIT_LINES if metric == "de76" else ():
                xs, ys = _series(kinds, names, "package", key)
                if xs:
                    ax.plot(xs, ys, style, label=label, ms=3, color="C0", alpha=0.6)
            ax.set_xscale("log")
            ticks = [x for k, x in names if k in kinds]
            ax.set_xticks(ticks, [f"{x:g}" for x in ticks])
            ax.minorticks_off()
            ax.set_xlabel("samples per slice")
            ax.set_ylabel("mean " + ("ΔE76" if metric == "de76" else "LogErr"))
            ax.set_title(f"{set_name} ({block['budget']}): error against density")
            ax.legend(fontsize=7)
    paths.append(_save(fig, folder / f"captures_density{suffix}.png"))
    fig, axes = plt.subplots(2, len(sets), figsize=(5.5 * len(sets), 7), squeeze=False)
    for j, (set_name, block) in enumerate(sets.items()):
        kinds = block["kinds"]
        for i, (group, xlabel, scale) in enumerate(
            (("noise", "relative value noise (%)", 100), ("jitter", "angle jitter σ (deg)", 1))
        ):
            ax = axes[i, j]
            names = [("protocol", 0.0)]
            names += [(k, v.x * scale) for k, v in KINDS.items() if v.group == group]
            for method, label, style in METHODS:
                xs, ys = _series(kinds, names, method)
                if xs:
                    ax.plot(xs, ys, style, label=label, ms=4)
            ax.set_xlabel(xlabel)
            ax.set_ylabel("mean ΔE76")
            ax.set_title(f"{set_name} ({block['budget']}): error against {group}")
            ax.legend(fontsize=7)
    paths.append(_save(fig, folder / f"captures_noise{suffix}.png"))
    return paths


def _save(fig, path: Path) -> str:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)
