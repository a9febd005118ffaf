"""Load (issue 16): a folder of 10,000 small measurement files and one 20 MiB CSV through
``abrdf-jax reconstruct``, with peak memory, wall time, files/s and what the user sees meanwhile.

Run: ``python -m benchmarks.load [--quick]``. Writes ``benchmarks/results/load.md`` and
``load.json`` (``--quick``: ``load_quick.*``: 1,000 files and a 2 MiB CSV).

Each command runs in its own process, launched by :mod:`benchmarks._timed_child` (wall time
around it, its own peak RSS from ``getrusage(RUSAGE_CHILDREN)``), with the load average read
before and after. The runs:

- a folder of ``small`` files (``reconstruct DIR -o OUT -q``) with a fresh, empty cache folder
  (compile included, as a user's first run), then again with the cache it filled, then the
  folder of ``large`` files with that cache: the peak RSS of the two warm runs says whether
  memory grows with the number of files (a cold run's peak is JAX's compile, ~0.5 GiB);
- the small folder again, warm, without ``-q``: the progress bars it shows (stderr);
- one dense aniso204 capture of ``csv_mib`` MiB (``reconstruct BIG.csv -o BIG.npz``, fresh cache,
  without ``-q``): peak RSS and the progress lines it prints.

Inputs: the built-in analytic materials (file ``i`` is material ``i mod 8``), each captured once
by :func:`abrdf_jax.simulate_capture` (iso102, the protocol's layout), every file with its own
1 % multiplicative value noise (seed ``SEED``), written by :func:`abrdf_jax.io.write_samples_csv`;
the CSV: ``ggx-aniso-metal``, aniso204, ``per_slice`` samples on each of its 8 slices, 1 % noise.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import abrdf_jax as aj
from abrdf_jax import io, materials

from ._common import RESULTS, load_average, machine, write_json
from .cli import CACHE_ENV

REPO = Path(__file__).resolve().parents[1]
SEED = 16
NOISE = 0.01
CSV_MATERIAL = "ggx-aniso-metal"
#: Folder sizes, samples per slice of the CSV (23,500 a slice: 20.0 MiB) of each mode.
SIZES = {
    "full": {"small": 1000, "large": 10_000, "per_slice": 23_500},
    "quick": {"small": 100, "large": 1000, "per_slice": 2350},
}


def write_folder(folder: Path, n: int, seed: int = SEED) -> Path:
    """``n`` iso102 measurement files: file ``i`` captures material ``i mod 8`` with its own noise."""
    names = materials.material_names()
    base = {
        m: aj.simulate_capture(materials.get_material(m), budget="iso102").to_numpy() for m in names
    }
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    for i in range(n):
        s = base[names[i % len(names)]]
        rgb = np.asarray(s.rgb) * (1 + NOISE * rng.standard_normal(np.shape(s.rgb)))
        one = aj.Samples(s.theta_i, s.phi_i, s.theta_v, s.phi_v, rgb)
        io.write_samples_csv(folder / f"{i:05d}-{names[i % len(names)]}.csv", one)
    return folder


def write_csv(path: Path, per_slice: int, seed: int = SEED) -> Path:
    """One dense aniso204 capture of :data:`CSV_MATERIAL`."""
    model = materials.get_material(CSV_MATERIAL)
    s = aj.simulate_capture(model, budget="aniso204", per_slice=per_slice, noise=NOISE, seed=seed)
    io.write_samples_csv(path, s)
    return path


def _progress_lines(stderr: str) -> list[str]:
    """What the user saw on stderr: each progress bar's last state and every message line."""
    seen: dict[str, str] = {}
    for part in stderr.replace("\r", "\n").splitlines():
        part = part.strip()
        if not part:
            continue
        key = part.split(":", 1)[0] if "%|" in part else part
        seen[key] = part  # a bar's later states replace its earlier ones
    return list(seen.values())


def timed(work: Path, name: str, cmd: list[str], env: dict, files: int) -> dict:
    """One process of ``cmd`` under :mod:`benchmarks._timed_child`: seconds, peak RSS, exit,
    stderr, load average before and after."""
    result = work / f"{name}.result.json"
    full_env = dict(os.environ) | env
    full_env["PYTHONPATH"] = str(REPO) + os.pathsep + full_env.get("PYTHONPATH", "")
    before = load_average()
    with open(work / f"{name}.stderr", "w+") as err, open(os.devnull, "w") as out:
        launch = [sys.executable, "-m", "benchmarks._timed_child", str(result), *cmd]
        subprocess.run(launch, env=full_env, cwd=work, stdout=out, stderr=err, check=True)
        err.seek(0)
        stderr = err.read()
    call = json.loads(result.read_text())
    shown = shlex.join(["python" if w == sys.executable else w for w in cmd])
    shown = " ".join(f"{k}=$WORK/{Path(v).name}" for k, v in env.items()) + " " + shown
    return {
        "command": shown.replace(str(work), "$WORK").strip(),
        "files": files,
        "seconds": call["seconds"],
        "files_per_s": files / call["seconds"],
        "peak_rss_mib": call["peak_rss_mib"],
        "exit_code": call["exit_code"],
        "load_before": before,
        "load_after": load_average(),
        "progress": _progress_lines(stderr),
    }


def run_all(work: Path, sizes: dict, log) -> dict:
    py = [sys.executable, "-m", "abrdf_jax.cli", "reconstruct"]
    t0 = time.perf_counter()
    log(f"writing {sizes['large']} files and a CSV of {sizes['per_slice']} samples a slice ...")
    large = write_folder(work / "large", sizes["large"])
    small = work / "small"
    small.mkdir()
    for p in sorted(large.iterdir())[: sizes["small"]]:
        os.link(p, small / p.name)
    csv = write_csv(work / "big.csv", sizes["per_slice"])
    inputs = {
        "seconds": time.perf_counter() - t0,
        "large_mib": sum(p.stat().st_size for p in large.iterdir()) / 2**20,
        "csv_mib": csv.stat().st_size / 2**20,
        "csv_samples": 8 * sizes["per_slice"],
    }
    log(
        f"  {inputs['seconds']:.0f} s; folder {inputs['large_mib']:.1f} MiB, CSV {inputs['csv_mib']:.1f} MiB"
    )

    def cache(name):
        (work / f"cache-{name}").mkdir()
        return {CACHE_ENV: str(work / f"cache-{name}")}

    runs, warm = {}, cache("folders")
    plan = [  # the first run fills the cache (compile included); the others find it warm
        ("small_cold", [*py, "small", "-o", "small.cold", "-q"], warm, sizes["small"]),
        ("small", [*py, "small", "-o", "small.out", "-q"], warm, sizes["small"]),
        ("large", [*py, "large", "-o", "large.out", "-q"], warm, sizes["large"]),
        ("small_progress", [*py, "small", "-o", "small.bars"], warm, sizes["small"]),
        ("csv", [*py, "big.csv", "-o", "big.npz"], cache("csv"), 1),
    ]
    for name, cmd, env, files in plan:
        run = runs[name] = timed(work, name, cmd, env, files)
        out = work / cmd[cmd.index("-o") + 1]
        run["outputs"] = len(list(out.glob("*.npz"))) if out.is_dir() else int(out.is_file())
        run["ok"] = run["exit_code"] == 0 and run["outputs"] == files
        log(
            f"  {name:15s} {run['seconds']:8.1f} s {run['files_per_s']:8.1f} files/s "
            f"{run['peak_rss_mib']:7.0f} MiB  exit {run['exit_code']}  load {run['load_after']}"
        )
    growth = runs["large"]["peak_rss_mib"] - runs["small"]["peak_rss_mib"]
    per_file = growth * 1024 / (sizes["large"] - sizes["small"])
    return {"inputs": inputs, "runs": runs, "rss_growth_kib_per_file": per_file}


def markdown(p: dict) -> str:
    r, i = p["runs"], p["inputs"]
    lines = [
        f"# Load ({p['mode']} run)",
        "",
        f"`{p['command']}` on {p['machine']['processor']} ({p['machine']['cpu_count']} CPUs), "
        f"{p['machine']['date']}, {p['seconds']:.0f} s in all. Load average before / after: "
        f"{p['load_average_before']} / {p['load_average_after']} (the machine was shared: wall "
        "times are upper bounds). Each row is one process (wall time around it, its own peak "
        "RSS); `$WORK` is the run's temporary folder.",
        "",
        f"Inputs: {p['sizes']['large']} iso102 files ({i['large_mib']:.1f} MiB; the small folder is "
        f"their first {p['sizes']['small']}), the 8 built-in analytic materials with 1 % value "
        f"noise each; one aniso204 capture of {CSV_MATERIAL}, {i['csv_samples']} samples, "
        f"{i['csv_mib']:.1f} MiB. Written in {i['seconds']:.0f} s (not counted).",
        "",
        "| run | command | files | s | files/s | peak RSS MiB | load before → after | exit |",
        "|---|---|---|---|---|---|---|---|",
    ]
    what = {
        "small_cold": "small folder, fresh cache",
        "small": "small folder, warm cache",
        "large": "large folder, warm cache",
        "small_progress": "small folder, warm cache, bars shown",
        "csv": f"one {i['csv_mib']:.0f} MiB CSV, fresh cache",
    }
    for k, run in r.items():
        lines.append(
            f"| {what[k]} | `{run['command']}` | {run['files']} | {run['seconds']:.1f} | "
            f"{run['files_per_s']:.1f} | {run['peak_rss_mib']:.0f} | {run['load_before'][0]} → "
            f"{run['load_after'][0]} | {run['exit_code']}{'' if run['ok'] else ' NOT OK'} |"
        )
    lines += [
        "",
        f"Memory: {p['rss_growth_kib_per_file']:.1f} KiB of peak RSS per file between the "
        f"{p['sizes']['small']}- and the {p['sizes']['large']}-file folders, warm (a folder of more than "
        "1024 files is checked whole, then read again in blocks of 1024; what grows is the model "
        "record, one entry of about 2 KiB per file). The CSV: "
        f"{r['csv']['peak_rss_mib']:.0f} MiB for {i['csv_mib']:.1f} MiB of text.",
        "",
        "What the user sees on stderr (the last state of each bar, every line):",
        "",
    ]
    for k in ("small_progress", "csv"):
        lines += [f"- {what[k]}:", "", "```", *r[k]["progress"], "```", ""]
    lines += [
        "A folder run's second bar is one bar, labelled 'select model' while a block's models are "
        "chosen and 'reconstruct' while its tables are computed and written: the 'select model' "
        "line above is that bar while the models were chosen.",
    ]
    return "\n".join(lines)


def main(argv=None, log=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1,000 files and a 2 MiB CSV")
    ap.add_argument("--out", type=Path, default=RESULTS, help="results folder")
    ap.add_argument("--report", action="store_true", help="rewrite the .md from the stored JSON")
    args = ap.parse_args(argv)
    log = log or (lambda s: print(s, flush=True))
    mode = "quick" if args.quick else "full"
    suffix = "_quick" if args.quick else ""
    if args.report:
        payload = json.loads((args.out / f"load{suffix}.json").read_text())
        (args.out / f"load{suffix}.md").write_text(markdown(payload))
        return payload
    argv_text = shlex.join(
        ["python", "-m", "benchmarks.load", *(sys.argv[1:] if argv is None else argv)]
    )
    payload = {
        "mode": mode,
        "command": argv_text,
        "machine": machine() | {"abrdf_jax": aj.__version__},
        "sizes": SIZES[mode],
        "load_average_before": load_average(),
    }
    log(f"load average {payload['load_average_before']}; {mode}: {SIZES[mode]}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="loadbench-") as tmp:
        payload |= run_all(Path(tmp), SIZES[mode], log)
    payload["seconds"] = time.perf_counter() - t0
    payload["load_average_after"] = load_average()
    args.out.mkdir(parents=True, exist_ok=True)
    md = markdown(payload)
    (args.out / f"load{suffix}.md").write_text(md)
    write_json(args.out / f"load{suffix}.json", payload)
    log(md)
    return payload


if __name__ == "__main__":
    main()
