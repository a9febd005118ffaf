"""The fresh-process runs of ``python -m benchmarks.btf``: the child (``--child MEAS OUT
[FORMAT]``: ``reconstruct_btf`` cold, then warm, with the command's allocator setting), its
launcher, and the headline's rounds of the largest size (module docstring of
:mod:`benchmarks.btf`)."""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

CHUNK = 1024


def child(argv) -> int:
    """``--child MEAS OUT [FORMAT]``: reconstruct twice (cold, then warm into OUT-warm) into the
    store format FORMAT (default npy); print JSON. The cold time is what ``abrdf-jax btf
    reconstruct`` does after its imports: the allocator setting (which starts JAX's backend to
    count the devices) and the call."""
    t0 = time.perf_counter()
    import jax

    from abrdf_jax import btf
    from abrdf_jax.cli.btf import keep_chunk_outputs

    meas, out, fmt = (*argv, "npy")[:3]
    t_import = time.perf_counter() - t0
    t = time.perf_counter()
    kept = keep_chunk_outputs(CHUNK, "float16")  # as `abrdf-jax btf reconstruct` sets it
    runs = []
    for k, target in enumerate((out, out + "-warm")):
        stats: dict = {}
        t = t if k == 0 else time.perf_counter()
        store = btf.reconstruct_btf(
            meas, target, chunk=CHUNK, progress=False, dtype="float16", stats=stats, format=fmt
        )
        runs.append(dict(stats, seconds=time.perf_counter() - t))  # the whole call
        if k == 1:
            shutil.rmtree(target)
    print(
        "RESULT "
        + json.dumps(
            dict(
                import_seconds=t_import,
                allocator_keeps_chunks=kept,
                cold=runs[0],
                warm=runs[1],
                texels=store.n_texels,
                devices=[str(d) for d in jax.devices()],
                peak_rss_bytes=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
                total_seconds=time.perf_counter() - t0,
            )
        )
    )
    return 0


#: The environment of a child that leaves glibc's allocator to its own rule: any ``MALLOC_*``
#: threshold variable means the user's setting (``abrdf_jax.cli._malloc``), and this one is
#: glibc's default trim threshold, so the mmap threshold stays glibc's dynamic one.
GLIBC_DEFAULT = {"MALLOC_TRIM_THRESHOLD_": "131072"}


def run_child(
    meas: Path, out: Path, devices: int | None = None, fmt: str = "npy", extra_env=None
) -> dict:
    env = dict(os.environ) | (extra_env or {})
    if devices is not None:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    t = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "benchmarks.btf", "--child", str(meas), str(out), fmt],
        env=env,
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    wall = time.perf_counter() - t
    if res.returncode != 0:
        raise RuntimeError(f"child failed:\n{res.stderr[-4000:]}")
    doc = json.loads([ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")][-1][7:])
    doc["process_wall_seconds"] = wall
    return doc


def headline(work: Path, big: int, first: dict, n_rounds: int, quick: bool) -> tuple[dict, dict]:
    """``(head, headline)``: ``n_rounds`` fresh-process runs of the ``big``² store (``first``,
    the size loop's run, is the first), the headline of the round of median cold time, the
    median warm time; in full mode each round is followed by one with glibc's own allocator
    thresholds (``GLIBC_DEFAULT``), the rounds interleaved: what ``keep_chunk_outputs`` gains,
    in the same run. ``head`` is the median round's child document."""
    rounds, default_alloc = [first], []
    for k in range(n_rounds):
        todo = ([] if k == 0 else [(rounds, {})]) + (
            [] if quick else [(default_alloc, GLIBC_DEFAULT)]
        )
        for into, env in todo:
            folder = work / f"round{k}{'-glibc' if env else ''}"
            into.append(run_child(work / f"btf{big}" / "measurements", folder, extra_env=env))
            shutil.rmtree(folder, ignore_errors=True)
            print(
                f"{big}x{big}, round {k + 1}{', glibc thresholds' if env else ''}: cold "
                f"{into[-1]['cold']['seconds']:.1f} s, warm {into[-1]['warm']['seconds']:.1f} s",
                flush=True,
            )
    head = sorted(rounds, key=lambda r: r["cold"]["seconds"])[(len(rounds) - 1) // 2]
    warm = sorted(r["warm"]["seconds"] for r in rounds)[(len(rounds) - 1) // 2]
    doc = dict(
        size=big,
        texels=big * big,
        samples_per_texel=204,
        store_dtype="float16",
        seconds_cold=head["cold"]["seconds"],
        seconds_warm=warm,
        rounds=[dict(cold=r["cold"]["seconds"], warm=r["warm"]["seconds"]) for r in rounds],
        process_wall_seconds=head["process_wall_seconds"],
        peak_rss_gib=max(r["peak_rss_bytes"] for r in rounds) / 2**30,
        texels_per_second_warm=big * big / warm,
        texels_per_second_cold=big * big / head["cold"]["seconds"],
        backend=head["warm"]["backend"],
        allocator_keeps_chunks=head.get("allocator_keeps_chunks"),
        target="<= 8 s cold on 2 cores, bounded by its own I/O (issue 13; was <= 60 s)",
        split={
            run: {
                stage: head[run].get(f"{stage}_seconds")
                for stage in ("build", "read", "compute", "write")
            }
            for run in ("cold", "warm")
        },
        store_bytes=sum(f.stat().st_size for f in (work / f"rec{big}" / "chunks").iterdir()),
    )
    if default_alloc:
        doc["glibc_thresholds"] = dict(
            rounds=[
                dict(cold=r["cold"]["seconds"], warm=r["warm"]["seconds"]) for r in default_alloc
            ],
            peak_rss_gib=max(r["peak_rss_bytes"] for r in default_alloc) / 2**30,
        )
    return head, doc
