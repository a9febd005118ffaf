"""The command line as a user runs it, against the scipy peer's command line (issue 13).

Run: ``python -m benchmarks.cli [--quick] [--peer-limit N] [--repeats K] [--folder-repeats R]``.
Writes ``benchmarks/results/cli.json`` and the README table ``cli.md`` (``--quick``:
``cli_quick.*``).

Everything runs in this one process tree and one run, each command a child process of the small
launcher :mod:`benchmarks._timed_child`, which times it by ``time.perf_counter`` around
``subprocess.run`` and reads its peak RSS from ``getrusage(RUSAGE_CHILDREN)`` (its one child; a
command forked straight from this process would inherit this process's RSS as its peak):

- the package: ``abrdf-jax --help`` (the installed entry point), a bad CSV (exit 2), one iso102
  file ``python -m abrdf_jax.cli reconstruct m.csv -o m.npz`` cold (``ABRDF_JAX_CACHE_DIR`` a fresh
  empty folder) and warm (the same folder, the median of ``--repeats`` further calls), one
  aniso204 file with ``--model auto``, with ``--model aniso`` and with ``--model auto --prior
  default`` (the learned models join the choice), one dense aniso204 capture (300 samples a
  slice, 0.5° of encoder jitter: a continuous capture's) with ``--model auto`` and ``--model
  aniso``, one iso102 file with the last (cold and warm each), 40 iso102 files one call each, two calls at a time (:mod:`benchmarks._parallel_calls`,
  what a shell loop with ``xargs -P 2`` does; warm), and folders
  ``reconstruct DIR -o OUT -q`` of 100 and 1000 iso102 files, 1000 aniso204 files, 200 iso102
  files and 200 aniso204 files with 0.5° of encoder jitter (:data:`JITTER_DEG`: each file's
  angles its own, as a real capture's, so each is a slice layout of its own: no one-stage map
  is shared), 8 aniso204 files (the
  built-in materials: ``--model auto`` gives them several models, each a small layout) and 16
  dense aniso204 captures (300 samples a slice, 0.5° jitter: a layout and an α each), each with a
  fresh cache (so compile is included, as the issue's targets say), then once more with the
  cache that run filled (warm: what a repeat run on the machine costs), ``--folder-repeats``
  rounds of both (default 3), each into a new output folder, the median of each kind (one
  folder call's time depends on the file system's state: a thousand files are created);
- the peer: :mod:`benchmarks.scipy_cli` (numpy/scipy only, the paper's setting) on the same
  inputs; on a folder of more than ``--peer-limit`` files it runs the first N (``--limit N``) and
  its time is scaled to the whole folder as ``start-up + (T_N - start-up) * files / N``, where
  start-up is the peer's ``--help`` (which imports numpy and scipy), so the peer's one start-up
  is not counted once per N files.

Inputs: the package's built-in analytic materials (:func:`abrdf_jax.materials.material_names`,
file ``i`` of a folder is material ``i mod 8``), captured by :func:`abrdf_jax.simulate_capture`
(protocol layout, 1 % relative value noise, seed ``SEED + i``, so no two files are equal) and
written with :func:`abrdf_jax.io.write_samples_csv`; nothing is downloaded. Issue 13's targets
are printed as PASS/FAIL lines (:func:`benchmarks._cli_report.check_targets`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

import abrdf_jax as aj
from abrdf_jax import io, materials

from ._cli_floors import floors
from ._cli_runner import (
    CACHE_ENV,
    PACKAGE,
    REPO,
    Runner,
    count_outputs,
    output_exists,
    median_run,
)
from ._cli_report import check_targets, derive, pass_fail_lines, write_reports
from ._common import RESULTS, load_average, machine, write_json

SEED = 13  # file i's capture's seed: SEED + i
NOISE = 0.01  # relative value noise of every capture (so that the files of a folder differ)
ISO_MATERIAL, ANISO_MATERIAL = "ggx-plastic", "ggx-aniso-metal"
#: Folder sizes of each mode (each folder's budget and jitter: :data:`FOLDERS`), and the files
#: of ``iso_small`` called one at a time, :data:`PARALLEL` calls at once (``iso_parallel``).
SIZES = {
    "full": {
        "iso_small": 100,
        "iso_large": 1000,
        "aniso_large": 1000,
        "iso_jitter": 200,
        "aniso_jitter": 200,
        "aniso_few": 8,
        "dense_few": 16,
        "iso_parallel": 40,
    },
    "quick": {
        "iso_small": 20,
        "iso_large": 50,
        "aniso_large": 50,
        "iso_jitter": 10,
        "aniso_jitter": 10,
        "aniso_few": 8,
        "dense_few": 4,
        "iso_parallel": 10,
    },
}
#: Encoder jitter (degrees) of the ``iso_jitter`` folder: each file's angles are its own (a real
#: capture's), so each is a slice layout of its own.
JITTER_DEG = 0.5
#: Samples a slice of the dense captures (a continuous capture's).
DENSE_PER_SLICE = 300
#: Each folder's budget, encoder jitter (degrees) and samples a slice (``None``: the budget's).
FOLDERS = {
    "iso_small": ("iso102", 0.0, None),
    "iso_large": ("iso102", 0.0, None),
    "aniso_large": ("aniso204", 0.0, None),
    "iso_jitter": ("iso102", JITTER_DEG, None),
    "aniso_jitter": ("aniso204", JITTER_DEG, None),  # several models: one shared second stage
    # a small folder of the 8 built-in materials: --model auto gives them several models, each
    # a layout of a few files (below OPERATOR_MIN_GROUP: built as operators, docs/cache.md)
    "aniso_few": ("aniso204", 0.0, None),
    # continuous captures of the 8 built-in materials (a layout and an α each): their
    # two-stage maps are shared by every file of a model (docs/cache.md)
    "dense_few": ("aniso204", JITTER_DEG, DENSE_PER_SLICE),
}
#: Folders run again with a model fixed: ``key: (folder, extra arguments)``; the row reuses the
#: folder's files and its peer. ``--model aniso`` is the recommended anisotropic model (the
#: min-max rule: a two-stage numpy entry, docs/cache.md).
FOLDER_MODELS = {"aniso_large_aniso": ("aniso_large", ["--model", "aniso"])}
#: Default ``--peer-limit``, ``--repeats`` and ``--folder-repeats`` of each mode.
PEER_LIMIT = {"full": 100, "quick": 10}
REPEATS = {"full": 3, "quick": 1}
FOLDER_REPEATS = {"full": 3, "quick": 1}
#: The row of one call per file, ``PARALLEL`` calls at a time (a shell loop with ``xargs -P``).
PARALLEL = 2
PEER = ("-m", "benchmarks.scipy_cli")


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------


def write_inputs(
    folder: Path,
    budget: str,
    n: int,
    models: dict,
    names: list[str] | None = None,
    jitter_deg: float = 0.0,
    per_slice: int | None = None,
) -> Path:
    """``n`` measurement CSV files in ``folder``: file ``i`` captures ``names[i % len(names)]``
    (angles with ``jitter_deg`` of encoder error; ``per_slice`` samples a slice, default the
    budget's)."""
    names = names or list(models)
    folder.mkdir(parents=True)
    for i in range(n):
        name = names[i % len(names)]
        s = aj.simulate_capture(
            models[name], budget=budget, noise=NOISE, seed=SEED + i, jitter_deg=jitter_deg,
            per_slice=per_slice,
        )  # fmt: skip
        io.write_samples_csv(folder / f"{i:04d}-{name}.csv", s)
    return folder


def write_bad_csv(path: Path) -> Path:
    """A measurement file whose third line holds a field that is not a number."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        "theta_i,phi_i,theta_v,phi_v,r,g,b\n30,0,30,345,0.1,0.1,0.1\n30,x,30,0,0.1,0.1,0.1\n"
    )
    return path


# --------------------------------------------------------------------------------------------
# The runs
# --------------------------------------------------------------------------------------------


def scale_peer(run: dict, files: int, startup: float) -> dict:
    """The peer's run on the first ``run["files"]`` files scaled to ``files`` (see the module doc)."""
    n, t = run["files"], run["seconds"]
    if n >= files:
        return run
    scaled = startup + (t - startup) * files / n
    return run | {"files": files, "seconds": scaled, "measured_seconds": t, "scaled_from": n}


#: The automatic choice with the default prior (RBF, prior only and fused compared by held-out
#: errors; numpy entries when warm).
PRIOR_AUTO = ["--model", "auto", "--prior", "default"]
#: One dense capture of ``ANISO_MATERIAL`` (a continuous capture's slices: ``DENSE_PER_SLICE``
#: samples a slice, :data:`JITTER_DEG` of encoder error) with these models.
SINGLE_DENSE = {"auto": ["--model", "auto"], "aniso": ["--model", "aniso"]}
#: The single aniso204 file's runs: ``tag: extra arguments``.
SINGLE_ANISO = {"auto": ["--model", "auto"], "aniso": ["--model", "aniso"], "prior": PRIOR_AUTO}


def single_file(r: Runner, key: str, csv: Path, extra: list[str], repeats: int) -> dict:
    """``reconstruct CSV -o OUT.npz EXTRA``: cold (fresh cache), then ``repeats`` warm calls."""
    py = sys.executable
    env = r.cache(key)
    cold_out, warm_out = csv.with_name(f"{key}-cold.npz"), csv.with_name(f"{key}-warm.npz")
    mk = lambda out: [py, *PACKAGE, "reconstruct", str(csv), "-o", str(out), *extra]  # noqa: E731
    cold = r.timed(mk(cold_out), files=1, env=env, outputs=output_exists(cold_out))
    warm = r.timed(mk(warm_out), files=1, env=env, repeats=repeats, outputs=output_exists(warm_out))
    return {"cold": cold, "warm": warm}


def folder_runs(
    r: Runner,
    key: str,
    folder: Path,
    files: int,
    peer_limit: int,
    startup: float,
    repeats: int = 1,
    extra: list[str] = (),
    peer: dict | None = None,
) -> dict:
    """``repeats`` rounds of a cold call (a fresh cache folder) and a warm call (the cache that
    cold call filled), each into an output folder of its own, the rounds in turn (so both see
    the disk in the same states); the median of each, then the peer once (``peer``: its row
    from an earlier call on the same folder). ``extra``: more arguments of every call."""
    py = sys.executable
    cold, warm = [], []
    for i in range(repeats):
        env = r.cache(key if i == 0 else f"{key}-{i}")
        for calls, tag in ((cold, "out"), (warm, "warm.out")):
            out = r.work / (f"{key}.{tag}" if i == 0 else f"{key}.{i}.{tag}")
            cmd = [py, *PACKAGE, "reconstruct", str(folder), "-o", str(out), "-q", *extra]
            calls.append(r.timed(cmd, files=files, env=env, outputs=count_outputs(out)))
    if peer is not None:
        return {"package": median_run(cold), "warm": median_run(warm), "peer": peer}
    n = min(files, peer_limit)
    pout = r.work / f"{key}.peer"
    pcmd = [py, *PEER, str(folder), "-o", str(pout)] + (["--limit", str(n)] if n < files else [])
    peer = r.timed(pcmd, files=n, cwd=REPO, outputs=count_outputs(pout))
    return {
        "package": median_run(cold),
        "warm": median_run(warm),
        "peer": scale_peer(peer, files, startup),
    }


def parallel_calls(r: Runner, folder: Path, files: int) -> dict:
    """The first ``files`` CSV files of ``folder``, one command-line call each, :data:`PARALLEL`
    at a time (:mod:`benchmarks._parallel_calls`), for the package (the cache of the one-file
    rows: warm) and the peer; and the package once more with ``OPENBLAS_NUM_THREADS`` set to the
    cores (OpenBLAS's own default, which the command otherwise replaces by one thread:
    ``abrdf_jax/cli/_blas.py``)."""
    py = sys.executable
    launch = [py, "-m", "benchmarks._parallel_calls", str(PARALLEL), str(files), str(folder)]
    env = {CACHE_ENV: str(r.work / "cache-iso1")}
    # the cores this process may run on: what the command restores OpenBLAS to after its runs
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cores = {"OPENBLAS_NUM_THREADS": str(n)}
    calls = {
        "package": ((*PACKAGE, "reconstruct"), {"env": env}),
        "peer": (PEER, {"cwd": REPO}),
        "blas": ((*PACKAGE, "reconstruct"), {"env": env | cores}),
    }
    run = {}
    for who, (tool, kw) in calls.items():
        out = r.work / f"parallel-{who}"
        cmd = [*launch, str(out), py, *tool, "{in}", "-o", "{out}"]
        run[who] = r.timed(cmd, files=files, outputs=count_outputs(out), **kw)
    what = f"{files} iso102 files, one call each, {PARALLEL} at a time (xargs -P {PARALLEL}), warm"
    blas = f"{what}, OpenBLAS on {cores['OPENBLAS_NUM_THREADS']} threads"
    return {
        "iso_parallel": {
            "what": what,
            "files": files,
            "package": run["package"],
            "peer": run["peer"],
        },
        "iso_parallel_blas": {
            "what": blas,
            "files": files,
            "package": run["blas"],
            "peer": run["peer"],
        },
    }


def run_all(r: Runner, sizes: dict, peer_limit: int, repeats: int, folder_repeats: int = 1) -> dict:
    py, work, log = sys.executable, r.work, r.log
    log("writing inputs ...")
    t0 = time.perf_counter()
    models = {n: materials.get_material(n) for n in materials.material_names()}
    one_iso = write_inputs(work / "one-iso102", "iso102", 1, models, [ISO_MATERIAL])
    one_aniso = write_inputs(work / "one-aniso204", "aniso204", 1, models, [ANISO_MATERIAL])
    one_dense = write_inputs(
        work / "one-dense", "aniso204", 1, models, [ANISO_MATERIAL], JITTER_DEG, DENSE_PER_SLICE
    )
    folders = {
        key: write_inputs(work / key, budget, sizes[key], models, None, jitter, per_slice)
        for key, (budget, jitter, per_slice) in FOLDERS.items()
    }
    bad = write_bad_csv(work / "bad" / "bad.csv")
    log(f"  {time.perf_counter() - t0:.1f} s")
    iso_csv, aniso_csv = next(one_iso.glob("*.csv")), next(one_aniso.glob("*.csv"))
    runs = {}
    h = max(repeats, 3)  # start-up figures are short: always a median of at least 3

    log("start-up and input errors")
    runs["help"] = {
        "what": "`--help`",
        "files": 1,
        "package": r.timed([*r.entry_point, "--help"], files=1, repeats=h),
        "peer": r.timed([py, *PEER, "--help"], files=1, cwd=REPO, repeats=h),
    }
    startup = runs["help"]["peer"]["seconds"]
    runs["input_error"] = {
        "what": "a bad CSV (exit 2)",
        "files": 1,
        "package": r.timed(
            [py, *PACKAGE, "reconstruct", str(bad), "-o", str(bad.with_suffix(".npz"))],
            files=1,
            repeats=h,
            expected_exit=2,
        ),
        "peer": r.timed(
            [py, *PEER, str(bad), "-o", str(bad.with_suffix(".peer.npz"))],
            files=1,
            cwd=REPO,
            repeats=h,
            expected_exit=2,
        ),
    }

    def peer_one(csv):  # the peer on one file
        pout = csv.with_name("peer.npz")
        cmd = [py, *PEER, str(csv), "-o", str(pout)]
        return r.timed(cmd, files=1, cwd=REPO, repeats=repeats, outputs=output_exists(pout))

    log("one iso102 file")
    peer_iso = peer_one(iso_csv)
    iso = single_file(r, "iso1", iso_csv, [], repeats)
    for state in ("cold", "warm"):
        what = f"one iso102 file, {state} cache"
        runs[f"iso1_{state}"] = {"what": what, "files": 1, "package": iso[state], "peer": peer_iso}

    log("one aniso204 file")
    peer_aniso = peer_one(aniso_csv)
    for tag, extra in SINGLE_ANISO.items():
        res = single_file(r, f"aniso1_{tag}", aniso_csv, extra, repeats)
        for state in ("cold", "warm"):
            runs[f"aniso1_{tag}_{state}"] = {
                "what": f"one aniso204 file, {' '.join(extra)}, {state} cache",
                "files": 1,
                "package": res[state],
                "peer": peer_aniso,
            }
    log("one dense capture")
    dense_csv = next(one_dense.glob("*.csv"))
    peer_dense = peer_one(dense_csv)
    for tag, extra in SINGLE_DENSE.items():
        res = single_file(r, f"dense1_{tag}", dense_csv, extra, repeats)
        for state in ("cold", "warm"):
            what = (
                f"one dense aniso204 capture ({DENSE_PER_SLICE} a slice, {JITTER_DEG:g} deg jitter)"
            )
            runs[f"dense1_{tag}_{state}"] = {
                "what": f"{what}, {' '.join(extra)}, {state} cache",
                "files": 1,
                "package": res[state],
                "peer": peer_dense,
            }
    log(f"iso102 files one call each, {PARALLEL} at a time")
    runs |= parallel_calls(r, folders["iso_small"], sizes["iso_parallel"])

    log("one iso102 file, --model auto --prior default")
    res = single_file(r, "iso1_prior", iso_csv, PRIOR_AUTO, repeats)
    for state in ("cold", "warm"):
        what = f"one iso102 file, {' '.join(PRIOR_AUTO)}, {state} cache"
        runs[f"iso1_prior_{state}"] = {"what": what, "files": 1, "package": res[state]}
        runs[f"iso1_prior_{state}"]["peer"] = peer_iso

    for key, folder in folders.items():
        n = sizes[key]
        log(f"folder {key}: {n} files")
        budget, jitter, per_slice = FOLDERS[key]
        res = folder_runs(r, key, folder, n, peer_limit, startup, folder_repeats)
        what = f"a folder of {n} {budget} files" + (
            f" with {jitter:g} deg jitter (a layout each)" if jitter else ""
        )
        what += f", {per_slice} samples a slice" if per_slice else ""
        runs[key] = {"what": f"{what}, cold cache", "files": n, "package": res["package"]}
        runs[key]["peer"] = res["peer"]
        runs[f"{key}_warm"] = {"what": f"{what}, warm cache", "files": n, "package": res["warm"]}
        runs[f"{key}_warm"]["peer"] = res["peer"]
    for key, (of, extra) in FOLDER_MODELS.items():
        n, peer = sizes[of], runs[of]["peer"]
        log(f"folder {of} with {' '.join(extra)}: {n} files")
        res = folder_runs(r, key, folders[of], n, peer_limit, startup, folder_repeats, extra, peer)
        what = f"a folder of {n} {FOLDERS[of][0]} files, {' '.join(extra)}"
        for tag, state in (("", "package"), ("_warm", "warm")):
            cache = "cold" if state == "package" else "warm"
            runs[key + tag] = {"what": f"{what}, {cache} cache", "files": n, "package": res[state]}
            runs[key + tag]["peer"] = peer
    derive(runs)
    return runs


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="folders of 20 and 50 files: a smoke test")
    ap.add_argument(
        "--peer-limit",
        type=int,
        help="the peer runs the first N files of a larger folder, its time scaled "
        f"(default {PEER_LIMIT['full']}, --quick {PEER_LIMIT['quick']})",
    )
    ap.add_argument(
        "--repeats",
        type=int,
        help=f"warm calls of one file, median taken (default {REPEATS['full']}, --quick {REPEATS['quick']})",
    )
    ap.add_argument(
        "--folder-repeats",
        type=int,
        help="rounds of a folder's cold and warm calls, median of each (default "
        f"{FOLDER_REPEATS['full']}, --quick {FOLDER_REPEATS['quick']})",
    )
    ap.add_argument("--out", type=Path, default=RESULTS, help="results folder")
    args = ap.parse_args(argv)
    args.mode = "quick" if args.quick else "full"
    args.sizes = SIZES[args.mode]
    args.peer_limit = PEER_LIMIT[args.mode] if args.peer_limit is None else args.peer_limit
    args.repeats = REPEATS[args.mode] if args.repeats is None else args.repeats
    if args.folder_repeats is None:
        args.folder_repeats = FOLDER_REPEATS[args.mode]
    if args.peer_limit < 2 or args.repeats < 1 or args.folder_repeats < 1:
        ap.error("--peer-limit must be at least 2, --repeats and --folder-repeats at least 1")
    return args


def main(argv=None, log=None) -> dict:
    args = parse_args(argv)
    log = log or (lambda s: print(s, flush=True))
    suffix = "_quick" if args.quick else ""
    argv_text = shlex.join(
        ["python", "-m", "benchmarks.cli", *(sys.argv[1:] if argv is None else argv)]
    )
    payload = {
        "mode": args.mode,
        "machine": machine() | {"abrdf_jax": aj.__version__},
        "load_average_before": load_average(),
        "commands": {"benchmark": argv_text},
        "sizes": args.sizes,
        "peer_limit": args.peer_limit,
        "repeats": args.repeats,
        "folder_repeats": args.folder_repeats,
        "inputs": {
            "what": f"Inputs: the {len(materials.material_names())} built-in analytic materials "
            f"(file i of a folder: material i mod 8; one file: {ISO_MATERIAL} iso102, "
            f"{ANISO_MATERIAL} aniso204), abrdf_jax.simulate_capture with {NOISE:.0%} value "
            f"noise, seed {SEED} + i.",
            "materials": materials.material_names(),
            "seed": SEED,
            "noise": NOISE,
        },
        "caches": f"Cold: {CACHE_ENV} a fresh empty folder; warm: the same folder again, the "
        f"median of {args.repeats} call(s); a folder runs {args.folder_repeats} round(s) of a "
        "cold call (a fresh cache, compile included) and a warm call (the cache that cold call "
        "filled), each into a new output folder, the median of each kind.",
        "bytecode": "Both commands' Python sources compiled to bytecode once before the runs "
        "(python -m compileall), as an installed package has them; a sync before every call "
        "(the earlier calls' outputs written back before it starts, not during it).",
        "peer_note": f"Peer: python -m benchmarks.scipy_cli (numpy/scipy, paper setting); on a "
        f"folder of more than {args.peer_limit} files it runs the first {args.peer_limit} and is "
        "scaled as start-up + (T_N - start-up) * files / N, start-up = its --help.",
    }
    log(
        f"load average {payload['load_average_before']}; mode {args.mode}, sizes {args.sizes}, "
        f"peer limit {args.peer_limit}, repeats {args.repeats}, folder repeats "
        f"{args.folder_repeats}"
    )
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="clibench-") as tmp:
        r = Runner(Path(tmp), log)
        payload["entry_point"] = r.entry_point
        payload["runs"] = run_all(r, args.sizes, args.peer_limit, args.repeats, args.folder_repeats)
        payload["floors"] = floors(Path(tmp), args.sizes["iso_large"], log)
    payload["seconds"] = time.perf_counter() - t0
    payload["load_average_after"] = load_average()
    payload["targets"] = check_targets(payload["runs"])
    args.out.mkdir(parents=True, exist_ok=True)
    md = write_reports(payload, args.out, suffix)
    write_json(args.out / f"cli{suffix}.json", payload)
    log(md)
    for line in pass_fail_lines(payload["targets"]):
        log(line)
    log(
        f"{payload['seconds']:.0f} s; load average after {payload['load_average_after']}; wrote {args.out / f'cli{suffix}.json'}"
    )
    return payload


if __name__ == "__main__":
    main()
