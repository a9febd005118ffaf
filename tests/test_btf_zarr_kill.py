"""A real crash of the zarr path (issue 15): ``abrdf-jax btf reconstruct --format zarr`` on a
64 x 64 BTF is killed by SIGKILL in a subprocess after some but not all of its chunks are on
disk, then resumed by rerunning the same command. The killed writer's lock file (and any
temporary chunk file) must not block the resume, the resumed run must keep the chunks already
written, and the finished group, read back through ``xarray.open_zarr`` and
``dask.array.from_zarr``, must equal an uninterrupted run of the same command (``--format npy``, run beside the killed
one) bit for bit. (The reference is a CLI run, not this process's ``reconstruct_btf``: the
tests enable 64-bit JAX, which builds the operator in float64, the CLI in float32.)

Every wait is bounded (``WAIT`` seconds) and fails with what the child said; the poll interval
only sets how soon the kill follows the first chunk, never whether the test passes.
"""

import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

pytest.importorskip("zarr")
xr = pytest.importorskip("xarray")
da = pytest.importorskip("dask.array")

from abrdf_jax import btf  # noqa: E402
from abrdf_jax.io._lock import lock_path  # noqa: E402
from cli_runner import REPO, run_cli  # noqa: E402

SIZE, CHUNK = 64, 256  # 16 chunks of four texel rows
N_CHUNKS = SIZE * SIZE // CHUNK
WAIT = 240  # seconds: the longest any one step may take on a loaded machine


def _chunk_files(store) -> list[str]:
    """The chunk keys under ``store/abrdf/c`` (names of digits: no temporary file)."""
    found = []
    for root, _, names in os.walk(store / "abrdf" / "c"):
        found += [os.path.join(root, n) for n in names if n.isdigit()]
    return found


def _temporaries(store) -> list[str]:
    return [
        os.path.join(root, n)
        for root, _, names in os.walk(store)
        for n in names
        if n.endswith((".tmp", ".partial"))
    ]


def _start(args, cwd, log) -> subprocess.Popen:
    """``abrdf-jax ARGS`` started with this checkout first on the path, its output to ``log``
    (a file, not a pipe: a full pipe would stall the child)."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with open(log, "w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "abrdf_jax.cli", *map(str, args)],
            cwd=cwd,
            env=env,
            stdout=f,
            stderr=subprocess.STDOUT,
        )


def _kill_after_first_chunk(args, cwd, out, log):
    """Start ``abrdf-jax ARGS``; SIGKILL it once a chunk of ``out`` is on disk. Returns the
    number of chunk files the killed process left."""
    child = _start(args, cwd, log)
    deadline = time.monotonic() + WAIT
    try:
        while not _chunk_files(out):
            if child.poll() is not None:
                pytest.fail(
                    f"the child ended (rc {child.returncode}) before a chunk: {log.read_text()}"
                )
            if time.monotonic() > deadline:
                pytest.fail(f"no chunk written in {WAIT} s: {log.read_text()[-2000:]}")
            time.sleep(0.002)
        child.send_signal(signal.SIGKILL)
        rc = child.wait(timeout=WAIT)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert rc == -signal.SIGKILL, (
        f"the reconstruction ended by itself (rc {rc}) before the kill: chunks are written too "
        f"fast for this test's window; use a smaller --chunk. Output: {log.read_text()[-2000:]}"
    )
    return len(_chunk_files(out))


def test_sigkill_mid_run_then_resume_equals_the_one_shot_result(tmp_path):
    btf.generate_btf(tmp_path / "D", SIZE, seed=1, reference=False, maps=False)
    out = tmp_path / "R.zarr"
    args = ("btf", "reconstruct", tmp_path / "D", "-o", out, "--format", "zarr")
    args += ("--chunk", CHUNK, "--quiet")

    one_shot = ("btf", "reconstruct", tmp_path / "D", "-o", tmp_path / "ref", "--chunk", CHUNK)
    reference = _start((*one_shot, "--quiet"), tmp_path, tmp_path / "ref.log")
    try:
        left = _kill_after_first_chunk(args, tmp_path, out, tmp_path / "killed.log")
        rc = reference.wait(timeout=WAIT)
    finally:
        if reference.poll() is None:
            reference.kill()
            reference.wait()
    assert rc == 0, (tmp_path / "ref.log").read_text()[-3000:]
    assert 1 <= left < N_CHUNKS, f"the kill left {left} of {N_CHUNKS} chunks: not mid-run"
    print(f"killed with {left} of {N_CHUNKS} chunks on disk")
    assert lock_path(out).exists(), "SIGKILL runs no cleanup: its lock file stays"
    killed = btf.open_store(out)
    done = killed.done_chunks(verify=True)
    # a chunk's name appears only once it is whole: every chunk file left decodes (crc32c)
    assert len(done) == left, (done, left)

    res = run_cli(*args, cwd=tmp_path, timeout=WAIT)
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"({N_CHUNKS - left} chunks computed, {left} already done)" in res.stdout, res.stdout
    assert "took over the lock" in res.stderr and "killed?" in res.stderr, res.stderr[-2000:]
    assert not lock_path(out).exists()
    assert _temporaries(out) == []

    values = btf.open_store(tmp_path / "ref").read()
    assert values.shape == (SIZE * SIZE, 6561, 3) and values.max() > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # complete: consolidated, so xarray does not warn
        ds = xr.open_zarr(out)
    np.testing.assert_array_equal(ds["abrdf"].values.reshape(values.shape), values)
    d = da.from_zarr(str(out), component="abrdf")
    np.testing.assert_array_equal(d.compute().reshape(values.shape), values)
