"""Faults of the run itself (issue 16): the output lock and the temporary files of killed writers."""

import os
import subprocess
import sys
import pytest

from abrdf_jax import InputError
from abrdf_jax.io._atomic import atomic_write, is_temp, remove_stale_temps, temp_owner
from abrdf_jax.io._lock import lock_path, output_lock


def test_temp_names_carry_the_writer_pid(tmp_path):
    out = tmp_path / "t.json"
    with atomic_write(out, "w") as f:
        (name,) = [p.name for p in tmp_path.iterdir() if is_temp(p.name)]
        assert temp_owner(name) == os.getpid()
        f.write("{}")
    assert [p.name for p in tmp_path.iterdir()] == ["t.json"]


def test_stale_temps_are_removed_live_ones_kept(tmp_path):
    out = tmp_path / "t.npz"
    dead = tmp_path / ".t.npz.999999999.abcdefgh.tmp"
    live = tmp_path / f".t.npz.{os.getppid()}.abcdefgh.tmp"
    other = tmp_path / ".u.npz.999999999.abcdefgh.tmp"
    for p in (dead, live, other):
        p.write_text("x")
    assert remove_stale_temps(out) == 1
    assert not dead.exists() and live.exists() and other.exists()
    assert remove_stale_temps(out, locked=True) == 1  # under the lock only ours are live
    assert not live.exists() and other.exists()


def test_second_writer_is_refused_naming_the_holder(tmp_path):
    out = tmp_path / "rec.npz"
    with output_lock(out) as lock:
        assert lock == lock_path(out) and f'"pid": {os.getpid()}' in lock.read_text()
        with pytest.raises(InputError, match=rf"being written by process {os.getpid()} on host"):
            with output_lock(out):
                pass
    assert not lock.exists()


def test_killed_holders_lock_is_taken_over_with_a_message(tmp_path):
    out = tmp_path / "store"
    code = f"from abrdf_jax.io._lock import output_lock\nimport time\nwith output_lock({str(out)!r}):\n"
    code += "    print('held', flush=True)\n    time.sleep(60)\n"
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "held"
    child.kill()
    child.wait()
    assert lock_path(out).exists()  # SIGKILL left the file (but not the flock)
    said = []
    with output_lock(out, warn=said.append):
        pass
    assert len(said) == 1 and f"process {child.pid}" in said[0] and "killed?" in said[0]
    assert not lock_path(out).exists()
