"""Output of :mod:`benchmarks.cli`: derived figures, issue 13's targets, the markdown table and
the chart of the ratios.

Imports neither JAX nor the package, so that the target checks and the table can be tested on a
made-up result (``tests/test_benchmark_cli.py``). A result is ``payload["runs"][key] =
{"what", "files", "package": run, "peer": run | None}`` where a run is what
:func:`benchmarks.cli.timed` returns (``seconds``, ``exit_code``, ``peak_rss_mib``, ...).
"""

from __future__ import annotations

import operator

GiB_MiB = 1024.0
_OPS = {"<=": operator.le, ">=": operator.ge}


def per_file(run: dict | None) -> float | None:
    """Seconds per file of a run (start-up, compile and I/O included), or ``None``."""
    if not run or not run.get("files") or run.get("seconds") is None:
        return None
    return run["seconds"] / run["files"]


def ratio(entry: dict) -> float | None:
    """Peer seconds per file over package seconds per file (> 1: the package is faster)."""
    a, b = per_file(entry.get("peer")), per_file(entry.get("package"))
    return None if a is None or not b else a / b


def derive(runs: dict) -> None:
    """Add ``s_per_file``, ``files_per_s`` to every run and ``ratio`` to every entry, in place."""
    for entry in runs.values():
        for who in ("package", "peer"):
            run = entry.get(who)
            if run:
                s = per_file(run)
                run["s_per_file"] = s
                run["files_per_s"] = None if not s else 1.0 / s
        entry["ratio"] = ratio(entry)


def _seconds(runs, key):
    run = runs.get(key, {}).get("package")
    return None if not run else run.get("seconds")


def _quotient(runs, top, bottom):
    a, b = _seconds(runs, top), _seconds(runs, bottom)
    return None if a is None or not b else a / b


def _cold_multiple(runs, key):
    """Package seconds over peer seconds (the inverse of the ratio) of one file."""
    r = runs.get(key, {}).get("ratio")
    return None if not r else 1.0 / r


def _rss(runs, key):
    run = runs.get(key, {}).get("package")
    return None if not run else run.get("peak_rss_mib")


def _failed_runs(runs) -> list[str]:
    out = []
    for key, entry in runs.items():
        for who in ("package", "peer"):
            run = entry.get(who)
            if run and not run.get("ok", False):
                out.append(f"{key}/{who}")
    return out


def _n(runs, key) -> str:
    return str(runs.get(key, {}).get("files", "?"))


#: ``(label, value(runs), op, limit, details(runs) | None)``; ``{n[key]}`` in a label is the file
#: count of run ``key``.
TARGETS = (
    ("`abrdf-jax --help` <= 0.3 s", lambda r: _seconds(r, "help"), "<=", 0.3, None),
    (
        "input error (bad CSV, exit 2) <= 0.5 s",
        lambda r: _seconds(r, "input_error"),
        "<=",
        0.5,
        None,
    ),
    (
        "one iso102 file, warm cache: ratio to the peer >= 1",
        lambda r: r.get("iso1_warm", {}).get("ratio"),
        ">=",
        1.0,
        None,
    ),
    (
        "one iso102 file, cold cache: package s / peer s <= 3",
        lambda r: _cold_multiple(r, "iso1_cold"),
        "<=",
        3.0,
        None,
    ),
    *(
        (
            f"{{n[{key}]}} {budget} files, one call, {state} cache: ratio per file >= {limit:g}",
            lambda r, k=key + suffix: r.get(k, {}).get("ratio"),
            ">=",
            limit,
            None,
        )
        for key, budget, limit in (
            ("iso_large", "iso102", 200.0),
            ("aniso_large", "aniso204", 100.0),
        )
        for state, suffix in (("cold", ""), ("warm", "_warm"))
    ),
    (
        "peak RSS of the {n[iso_large]}-file iso102 run <= 1 GiB (MiB)",
        lambda r: _rss(r, "iso_large"),
        "<=",
        GiB_MiB,
        None,
    ),
    (
        "peak RSS of the {n[aniso_large]}-file aniso204 run <= 1 GiB (MiB)",
        lambda r: _rss(r, "aniso_large"),
        "<=",
        GiB_MiB,
        None,
    ),
    (
        "one aniso204 file, warm: --model auto s / --model aniso s <= 2",
        lambda r: _quotient(r, "aniso1_auto_warm", "aniso1_aniso_warm"),
        "<=",
        2.0,
        None,
    ),
    (
        "one aniso204 file, cold: --model auto s / --model aniso s <= 2",
        lambda r: _quotient(r, "aniso1_auto_cold", "aniso1_aniso_cold"),
        "<=",
        2.0,
        None,
    ),
    *(
        (
            f"one dense aniso204 capture, {state} (beyond the issue's protocol file): "
            "--model auto s / --model aniso s <= 2",
            lambda r, st=state: _quotient(r, f"dense1_auto_{st}", f"dense1_aniso_{st}"),
            "<=",
            2.0,
            None,
        )
        for state in ("warm", "cold")
    ),
    (
        "every run exits as expected and writes every output (runs failing)",
        lambda r: len(_failed_runs(r)),
        "<=",
        0,
        _failed_runs,
    ),
)


def check_targets(runs: dict) -> list[dict]:
    """Every target of :data:`TARGETS`: ``{"target", "value", "op", "limit", "pass"}``.

    A value that could not be measured (a run missing or failed) is ``None`` and fails.
    """
    n = {key: _n(runs, key) for key in ("iso_large", "aniso_large")}
    out = []
    for label, value, op, limit, details in TARGETS:
        try:
            v = value(runs)
        except (KeyError, TypeError, ZeroDivisionError):
            v = None
        row = {"target": label.format(n=n), "value": v, "op": op, "limit": limit}
        row["pass"] = v is not None and _OPS[op](v, limit)
        if details is not None:
            row["failed"] = details(runs)
        out.append(row)
    return out


def _f(x, fmt=".3g") -> str:
    return "–" if x is None else format(x, fmt)


def _row(entry: dict, who: str) -> str:
    run = entry[who]
    note = ""
    if run.get("repeats", 1) > 1:
        note = f" (median of {run['repeats']})"
    if run.get("scaled_from"):
        note = f" (scaled from {run['scaled_from']} files)"
    r = entry.get("ratio") if who == "package" else None
    return (
        f"| {entry['what']} | {who} | `{run['shown']}` | {entry['files']} | {_f(run['seconds'])}{note} | "
        f"{_f(run.get('files_per_s'))} | {_f(run.get('s_per_file'))} | {_f(r)} | "
        f"{_f(run.get('peak_rss_mib'), '.0f')} | {run['exit_code']} |"
    )


def _floors(f: dict | None) -> list[str]:
    """The machine's floors of a folder run (``benchmarks.cli.floors``), as a paragraph."""
    if not f:
        return []
    return [
        f"This machine's floors: writing {f['files']} tables took {f['write_tables_s']:.2f} s "
        f"and parsing {f['files']} iso102 CSV files {f['parse_csv_s']:.2f} s ({f['what']}).",
        "",
    ]


def markdown(payload: dict, image: str | None = None) -> str:
    runs = payload["runs"]
    m = payload["machine"]
    out = [
        f"# The command line against the scipy peer's command line ({payload['mode']} run)",
        "",
        f"`{payload['commands']['benchmark']}` on {m.get('processor')} ({m.get('cpu_count')} "
        f"CPUs, {m.get('platform')}), {m.get('date')}. Load average before / after: "
        f"{payload['load_average_before']} / {payload['load_average_after']}; "
        f"{payload['seconds']:.0f} s in all. Each row is one process (wall time around it, peak "
        "RSS of that process); `$WORK` is the run's temporary folder. "
        f"{payload['inputs']['what']} {payload['caches']} {payload.get('bytecode', '')} "
        f"{payload['peer_note']}",
        "",
        *_floors(payload.get("floors")),
        "| run | who | command | files | s | files/s | s per file | ratio | peak RSS MiB | exit |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    shown = set()  # a peer run shared by several entries (cold and warm) is one row
    for entry in runs.values():
        out.append(_row(entry, "package"))
        peer = entry.get("peer")
        if peer and id(peer) not in shown:
            shown.add(id(peer))
            out.append(_row(entry, "peer"))
    out += [
        "",
        "ratio = peer s per file / package s per file (above 1: the package is faster).",
        *(["", f"![the ratio of every row, cold and warm]({image})"] if image else []),
        "",
        "## Targets (issue 13)",
        "",
        "| target | value | limit | result |",
        "|---|---|---|---|",
    ]
    for t in payload["targets"]:
        v = _f(t["value"])
        if t.get("failed"):
            v += " failed: " + ", ".join(t["failed"])
        out.append(
            f"| {t['target']} | {v} | {t['op']} {t['limit']:g} | "
            f"{'PASS' if t['pass'] else 'FAIL'} |"
        )
    if payload["mode"] == "quick":
        out += ["", "Quick run: a smoke test of the harness (small folders), not figures to quote."]
    return "\n".join(out) + "\n"


_STATES = {", cold cache": 0, ", warm cache": 1, ", warm": 1}


def chart_rows(runs: dict) -> list[tuple[str, float | None, float | None, float | None]]:
    """``(label, cold ratio, warm ratio, other ratio)`` of every run with a peer: a cold call
    and its warm one on one row, a run that names no cache state (``--help``, a bad file, a
    run with other settings) as ``other`` (``None``: not measured that way), in the table's
    order."""
    rows: dict[str, list] = {}
    for entry in runs.values():
        what = entry["what"]
        state = next((st for st in _STATES if what.endswith(st)), None)
        label = what[: len(what) - len(state)] if state else what
        rows.setdefault(label, [None, None, None])[_STATES.get(state, 2)] = entry.get("ratio")
    return [(label, *values) for label, values in rows.items()]


def chart(payload: dict, path) -> None:
    """The ratio to the peer of every row (log scale), cold and warm, with parity and issue
    13's folder targets (100x aniso204, 200x iso102) as lines."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = chart_rows(payload["runs"])
    fig, ax = plt.subplots(figsize=(11, 0.42 * len(rows) + 1.6))
    ys = range(len(rows))
    kinds = (
        (-0.2, 1, "cold cache (first call)", "C0"),
        (0.2, 2, "warm cache", "C1"),
        (0.0, 3, "one kind of call", "0.6"),
    )
    for dy, k, name, color in kinds:
        at = [(y + dy, r[k]) for y, r in zip(ys, rows) if r[k]]
        if at:
            ax.barh(*zip(*at), height=0.38, label=name, color=color)
    for x, text in ((1, "parity"), (100, "100x"), (200, "200x")):
        ax.axvline(x, color="grey", lw=0.8, ls="--")
        ax.text(x, -0.7, f" {text}", fontsize=7, color="grey")
    ax.set_xscale("log")
    ax.set_yticks(list(ys))
    ax.set_yticklabels([textwrap.fill(r[0], 44) for r in rows], fontsize=7)
    ax.set_ylim(len(rows) - 0.5, -1.0)
    ax.set_xlabel("peer seconds per file / package seconds per file (above 1: abrdf-jax faster)")
    ax.legend(fontsize=8, loc="center right")
    m = payload["machine"]
    ax.set_title(
        f"{payload['commands']['benchmark']}, {m.get('date')}, {m.get('cpu_count')} CPUs, "
        f"load {payload['load_average_before'][0]:.2f} before",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def write_reports(payload: dict, folder, suffix: str) -> str:
    """``cli{suffix}.md`` (the table, the targets) and ``cli{suffix}.png`` (:func:`chart`) in
    ``folder``; returns the markdown."""
    from pathlib import Path

    folder = Path(folder)
    chart(payload, folder / f"cli{suffix}.png")
    md = markdown(payload, f"cli{suffix}.png")
    (folder / f"cli{suffix}.md").write_text(md)
    return md


def pass_fail_lines(targets: list[dict]) -> list[str]:
    """One ``PASS``/``FAIL`` line per target, for the console."""
    out = []
    for t in targets:
        v = _f(t["value"])
        if t.get("failed"):
            v += " failed: " + ", ".join(t["failed"])
        out.append(
            f"{'PASS' if t['pass'] else 'FAIL'}  {t['target']}: {v} ({t['op']} {t['limit']:g})"
        )
    return out
