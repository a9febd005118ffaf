"""This machine's floors of a folder run (part of ``python -m benchmarks.cli``): what writing the
tables and parsing the CSV files cost by themselves."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np

from abrdf_jax import io


def floors(work: Path, n: int, log) -> dict:
    """What this machine's disk and one core cost a folder run, measured in this process after
    the runs (the folder ``iso_large`` exists): ``n`` tables written by
    ``abrdf_jax.io.write_tables`` (one thread, fresh folder, after a ``sync``), and the ``n``
    iso102 CSV files parsed by ``abrdf_jax.io.read_sample_columns`` (one core, warm page cache).
    A folder run cannot be faster than the larger of the two by more than its parallelism."""
    rng = np.random.default_rng(0)
    tables = rng.random((n, 81, 81, 3), dtype=np.float32)
    out = work / "floor-writes"
    out.mkdir()
    if hasattr(os, "sync"):
        os.sync()
    t0 = time.perf_counter()
    io.write_tables([out / f"{k:04d}.npz" for k in range(n)], tables)
    write_s = time.perf_counter() - t0
    shutil.rmtree(out)
    files = sorted((work / "iso_large").glob("*.csv"))[:n]
    t0 = time.perf_counter()
    for f in files:
        io.read_sample_columns(f)
    parse_s = time.perf_counter() - t0
    log(
        f"floors: {n} tables written in {write_s:.2f} s, {len(files)} CSV files parsed in {parse_s:.2f} s"
    )
    return {
        "what": f"{n} tables (79 kB .npz each) written by abrdf_jax.io.write_tables in one thread "
        f"(fresh folder, after sync), and {len(files)} iso102 CSV files parsed by "
        "abrdf_jax.io.read_sample_columns on one core, in the benchmark's process after the runs",
        "write_tables_s": write_s,
        "parse_csv_s": parse_s,
        "files": len(files),
    }
