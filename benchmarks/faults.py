"""Killed at any point (issue 16): SIGKILL ``reconstruct DIR``, ``btf reconstruct`` and ``fit self``
at seeded moments, rerun each to completion and check what was left and what came out.

Run: ``python -m benchmarks.faults [--quick] [--points N] [--seed S] [--only NAME ...]``.
Writes ``benchmarks/results/faults.md`` and ``faults.json`` (``--quick``: ``faults_quick.*``, 5
points per command); with ``--only`` the other commands' rows are kept from the stored JSON.

Each command runs once uninterrupted (the reference, cold: its compilation cache folder starts
empty) and once more (warm: the kill window), then for each kill point in a fresh output folder:
started, killed with SIGKILL at a moment drawn (seeded) between its start and its expected end
(the latest uninterrupted warm runs' median) or, every other point, as soon as a drawn number
of its pieces (tables, chunks) is on disk; checked (every output absent, or complete and
valid), rerun to completion (``reconstruct`` with ``--resume``) and checked again: the result
bit-identical to the reference, no temporary or lock file left, the record valid
(:mod:`benchmarks._kill`, the harness ``tests/test_kill.py`` runs with a few points). A kill point whose run ended before its moment came is counted apart
("ended first"); it is still checked. Exit status 1 when any check failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from . import _kill_commands as kc
from ._common import RESULTS, load_average, write_json
from ._kill import Point, Report, kill_points

#: name -> (inputs into a folder -> the Command), full and quick sizes.
SIZES = {
    "full": {"captures": 96, "btf": 32, "chunk": 128, "steps": 3, "points": 20},
    "quick": {"captures": 64, "btf": 32, "chunk": 128, "steps": 2, "points": 5},
}
SEED = 16
NAMES = ("reconstruct", "btf", "fit")


def commands(inputs: Path, size: dict) -> dict:
    """The three commands on inputs made in ``inputs`` (name -> factory, inputs made lazily)."""
    return {
        "reconstruct": lambda: kc.reconstruct_dir(
            kc.write_captures(inputs / "caps", size["captures"])
        ),
        "btf": lambda: kc.btf_reconstruct(kc.write_btf(inputs / "D", size["btf"]), size["chunk"]),
        "fit": lambda: kc.fit_self(
            kc.write_captures(inputs / "one", 1, seed=7) / "c000.csv", size["steps"]
        ),
    }


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in load_average())


def _row(r: Report) -> str:
    killed = sum(p.killed for p in r.points)
    with_pieces = sum(p.killed and 0 < p.pieces < r.total_pieces for p in r.points)
    temps = sum(p.temps for p in r.points)
    locks = sum(p.lock for p in r.points)
    reruns = [p.rerun_s for p in r.points if p.rerun_s]
    said = [p.kept for p in r.points if p.kept is not None]
    kept = sum(k > 0 for k in said) if said or not r.points else "-"  # "-": not recorded
    rerun = f"{min(reruns):.1f}-{max(reruns):.1f}" if reruns else "-"
    first = "-" if r.first_piece_s is None else f"{r.first_piece_s:.1f}"
    return (
        f"| {r.command} | {len(r.points)} | {killed} | {len(r.points) - killed} | {with_pieces} "
        f"| {r.total_pieces} | {temps} | {locks} | {r.reference_s:.1f} | {r.warm_s:.1f} | {first} "
        f"| {rerun} | {kept} | {r.cache_temps} | {len(r.failed)} |"
    )


HEADER = (
    "| command | points | killed | ended first | killed mid-output | pieces | temps left by "
    "kills | locks left by kills | reference s | warm s | first piece s | rerun s | reruns that kept "
    "pieces | cache temps | problems |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def report_md(reports: list[Report], metas: list[dict]) -> str:
    """The Markdown report: one row per command, the run each row comes from, every problem."""
    lines = [
        "# Killed at any point (`python -m benchmarks.faults`)",
        "",
        HEADER,
        *(_row(r) for r in reports),
        "",
        "*killed mid-output*: killed with some but not all pieces (tables, chunks) on disk. "
        "*temps/locks left by kills*: what the killed runs left, all removed by the reruns "
        "(a problem otherwise). *reference s*: the uninterrupted run with an empty cache folder; "
        "*warm s*: the second one (the kill window); *rerun s*: the reruns to completion after "
        "a kill; *reruns that kept pieces*: of those, the ones that kept tables or chunks of "
        "the killed runs (`reconstruct --resume`: the tables its model record listed). *cache "
        "temps*: temporary files left in the compilation/operator cache (removed after an hour "
        "by the next run that uses the cache).",
        "",
        "Runs:",
        "",
    ]
    for r, m in zip(reports, metas):
        lines.append(
            f"- {r.command}: {m['date']}, `python -m benchmarks.faults"
            + (" --quick" if m["mode"] == "quick" else "")
            + f"` ({m['points']} points, seed {r.seed}, sizes {m['sizes']}), {m['seconds']:.0f} "
            f"s, {m['platform']}, {m['cpus']} CPUs, load average {m['load_before']} before, "
            f"{m['load_after']} after"
        )
    lines += ["", "Problems found:", ""]
    for r in reports:
        lines += [f"- {r.command}: {m}" for m in r.failed] or [f"- {r.command}: none"]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.faults", description=__doc__)
    ap.add_argument("--quick", action="store_true", help="5 kill points per command")
    ap.add_argument("--points", type=int, help="kill points per command (default 20, quick 5)")
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--only", nargs="*", choices=NAMES, help="run only these commands")
    ap.add_argument("--out", type=Path, default=RESULTS, help="output folder")
    args = ap.parse_args(argv)
    mode = "quick" if args.quick else "full"
    size = SIZES[mode]
    n = args.points or size["points"]
    stem = "faults" if mode == "full" else "faults_quick"
    runs = _stored(args.out / f"{stem}.json", args.only)
    failed = False
    with tempfile.TemporaryDirectory(prefix="abrdf-faults-") as tmp:
        tmp = Path(tmp)
        for k, (name, make) in enumerate(commands(tmp / "inputs", size).items()):
            if args.only and name not in args.only:
                continue
            t0, load_before = time.perf_counter(), _load()
            cmd = make()
            print(f"{cmd.name}: reference run, then {n} kill points (load {load_before})")
            r = kill_points(cmd, tmp / name, n, args.seed + k, say=_say)
            failed = failed or bool(r.failed)
            print(HEADER.splitlines()[0] + "\n" + _row(r), flush=True)
            meta = {
                "mode": mode,
                "date": time.strftime("%Y-%m-%d %H:%M:%S"),
                "platform": platform.platform(),
                "cpus": os.cpu_count(),
                "load_before": load_before,
                "load_after": _load(),
                "points": n,
                "sizes": size,
                "seconds": time.perf_counter() - t0,
            }
            runs = [d for d in runs if d["name"] != name] + [_as_json(r, name) | {"meta": meta}]
    runs.sort(key=lambda d: NAMES.index(d["name"]))
    md = report_md([_from_json(d) for d in runs], [d["meta"] for d in runs])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{stem}.md").write_text(md)
    write_json(args.out / f"{stem}.json", {"reports": runs})
    print("\n" + md)
    return 1 if failed else 0


def _say(message: str) -> None:
    print(message, flush=True)


def _as_json(r: Report, name: str) -> dict:
    d = dict(vars(r))
    d["points"] = [dict(vars(p)) for p in r.points]
    d["failed"] = r.failed
    d["name"] = name
    return json.loads(json.dumps(d, default=str))


def _from_json(d: dict) -> Report:
    fields = {k: v for k, v in d.items() if k not in ("failed", "name", "meta", "points")}
    return Report(**fields, points=[Point(**p) for p in d["points"]])


def _stored(path: Path, only) -> list[dict]:
    """With ``--only``: the stored runs of the other commands (their own ``meta``)."""
    if not only or not path.exists():
        return []
    try:
        doc = json.loads(path.read_text())
    except ValueError:
        return []
    return [d for d in doc.get("reports", []) if d.get("name") not in only and "meta" in d]


if __name__ == "__main__":
    sys.exit(main())
