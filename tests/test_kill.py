"""Killed at any point (issue 16), the short version: ``reconstruct DIR`` is killed with SIGKILL
at a few seeded moments and rerun with ``--resume``; whatever a kill left must be absent or
complete and valid, the finished tables and record bit-identical to an uninterrupted run, and
no temporary or lock file left (the harness: ``benchmarks/_kill.py``). The long version, 20
points per command, with ``btf reconstruct`` and ``fit self`` too: ``python -m
benchmarks.faults``. Those two are not here because each of their runs costs seconds of JAX
import and tracing, and a kill test needs at least three: a 16 x 16 BTF took 125 s at load
average 10 (2026-12-03); a killed ``btf reconstruct --format zarr`` is tested in CI by
``tests/test_btf_zarr_kill.py``.

The kill points are chained (each kills the rerun of the one before in the same output folder,
only the last runs to completion), so the test costs three complete runs (the reference, with an
empty cache folder; a second one, warm as the killed ones, that times the kill window; the last
rerun) and the killed ones. The seed is ``ABRDF_KILL_SEED`` (default 16), printed on failure.
"""

import os

from benchmarks import _kill_commands as kc
from benchmarks._kill import kill_points

SEED = int(os.environ.get("ABRDF_KILL_SEED", "16"))
POINTS = 3
WAIT = 300.0  # seconds: the longest one run may take on a loaded machine


def _run(cmd, root, seed):
    report = kill_points(cmd, root, POINTS, seed, chain=True, timeout=WAIT)
    summary = [
        f"{'killed' if p.killed else 'ended first'} (at piece {p.target} or {p.at:.2f} s) "
        f"with {p.pieces} of {report.total_pieces} piece(s) on disk"
        for p in report.points
    ]
    assert not report.failed, f"seed {seed}: " + "\n".join(report.failed)
    assert len(report.points) == POINTS
    assert any(p.killed for p in report.points), f"seed {seed}: every run ended before its kill"
    print(f"{cmd.name} (seed {seed}):", "; ".join(summary))
    return report


def test_reconstruct_dir_killed_and_resumed(tmp_path):
    # 64 captures at two slice offsets: two operator groups; the tables appear one by one
    caps = kc.write_captures(tmp_path / "caps", 64)
    report = _run(kc.reconstruct_dir(caps), tmp_path / "run", SEED)
    assert report.total_pieces == 64
