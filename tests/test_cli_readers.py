"""A folder's inputs read by worker processes (``abrdf_jax.cli._readers``, issue 13).

The parallel reader must be invisible but for the time: the same tables bit for bit, the same
model record, the same console lines in the same order, the same refusal naming the same files
and lines. Each case runs the command line in a subprocess (the readers fork only in a process
that has not imported JAX) with ``ABRDF_JAX_READERS`` = 2 and = 1 (serial) and compares.
"""

import json

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials
from abrdf_jax._errors import InputError
from abrdf_jax.cli import _readers
from tests.cli_runner import run_cli


def _folder(path, n=6, budget="iso102"):
    """``n`` noisy captures of the built-in materials; file 1 lacks the 75/75 pair (a warning),
    file 2 has negative values (a warning after the read)."""
    path.mkdir()
    names = materials.material_names()
    for k in range(n):
        s = aj.simulate_capture(
            materials.get_material(names[k % len(names)]), budget=budget, noise=0.01, seed=k
        )
        cols = [np.asarray(getattr(s, f)) for f in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")]
        if k == 1:  # no sample at 75/75
            keep = ~(np.isclose(cols[0], 75.0) & np.isclose(cols[2], 75.0))
            cols = [c[keep] for c in cols]
        if k == 2:
            cols[4] = cols[4].copy()
            cols[4][3, 1] = -0.01
        s = aj.Samples(*cols)
        io.write_samples_csv(path / f"m{k:02d}.csv", s)
    return path


def _untimed(record):
    """A model record without its timings (``"seconds"``)."""
    if isinstance(record, dict):
        return {k: _untimed(v) for k, v in record.items() if k != "seconds"}
    if isinstance(record, list):
        return [_untimed(v) for v in record]
    return record


def _said(err: str) -> list[str]:
    """The command's own lines (warnings, errors) in order, without the progress bars."""
    return [line for line in err.splitlines() if line.startswith("abrdf-jax:")]


def _run(tmp_path, monkeypatch, readers, inputs, out, *extra):
    monkeypatch.setenv(_readers.READERS_ENV, str(readers))
    return run_cli(
        "reconstruct", inputs, "-o", out, "--cache-dir", tmp_path / "cache", *extra, cwd=tmp_path
    )


def test_parallel_read_gives_the_serial_tables_record_and_lines(tmp_path, monkeypatch):
    inputs = _folder(tmp_path / "in")
    runs = {r: _run(tmp_path, monkeypatch, r, inputs, tmp_path / f"out{r}") for r in (1, 2)}
    for r, p in runs.items():
        assert p.returncode == 0, (r, p.stderr)
    serial, parallel = runs[1], runs[2]
    assert "75" in serial.stderr and "negative values" in serial.stderr  # the warnings are there
    assert _said(parallel.stderr.replace("out2", "out1")) == _said(serial.stderr)
    assert parallel.stdout.replace("out2", "out1") == serial.stdout
    for f in sorted(inputs.glob("*.csv")):
        a = io.read_table(tmp_path / "out1" / f"{f.stem}.npz")
        b = io.read_table(tmp_path / "out2" / f"{f.stem}.npz")
        np.testing.assert_array_equal(a, b)
    records = [json.loads((tmp_path / f"out{r}.model.json").read_text()) for r in (1, 2)]
    assert _untimed(records[0]) == _untimed(records[1])


@pytest.mark.parametrize("bad_plan", [False, True], ids=["unreadable value", "too few samples"])
def test_parallel_read_refuses_bad_files_as_the_serial_reader(tmp_path, monkeypatch, bad_plan):
    inputs = _folder(tmp_path / "in", n=5)
    lines = (inputs / "m03.csv").read_text().splitlines()
    if bad_plan:  # read fine, refused when grouped: three samples
        (inputs / "m03.csv").write_text("\n".join(lines[:4]) + "\n")
    else:
        lines[6] = lines[6].replace(",", ",x", 1)
        (inputs / "m03.csv").write_text("\n".join(lines) + "\n")
    runs = {r: _run(tmp_path, monkeypatch, r, inputs, tmp_path / f"out{r}") for r in (1, 2)}
    for r, p in runs.items():
        assert p.returncode == 2, (r, p.stderr)
        assert "m03.csv" in p.stderr and "Traceback" not in p.stderr
        assert not (tmp_path / f"out{r}").exists()
    if not bad_plan:
        assert "m03.csv:7" in runs[2].stderr  # the line of the bad value
    assert _said(runs[2].stderr.replace("out2", "out1")) == _said(runs[1].stderr)


def test_reader_count_rules(tmp_path, monkeypatch):
    files = [tmp_path / f"f{k}.csv" for k in range(_readers.PARALLEL_MIN)]
    for f in files:
        f.write_text("x\n")
    monkeypatch.delenv(_readers.READERS_ENV, raising=False)
    assert _readers.reader_count(files[:-1]) == 1  # below PARALLEL_MIN: this process
    # this test process has imported JAX: forking it is not safe, so it reads itself
    assert _readers.reader_count(files) == 1
    monkeypatch.setattr(_readers, "_fork_is_safe", lambda: True)
    monkeypatch.setattr(_readers, "cores", lambda: 2)
    assert _readers.reader_count(files) == 2
    monkeypatch.setenv(_readers.READERS_ENV, "3")
    assert _readers.reader_count(files[:5]) == 3  # the variable overrides the folder size
    monkeypatch.setenv(_readers.READERS_ENV, "1")
    assert _readers.reader_count(files) == 1
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(_readers.READERS_ENV, bad)
        with pytest.raises(InputError, match=_readers.READERS_ENV):
            _readers.reader_count(files)
    monkeypatch.setenv(_readers.READERS_ENV, "2")
    monkeypatch.setattr(_readers, "BIG_FILE_BYTES", 1)  # a file to announce: read serially
    assert _readers.reader_count(files) == 1


def test_bad_readers_variable_is_a_clean_error(tmp_path, monkeypatch):
    inputs = _folder(tmp_path / "in", n=2)
    p = _run(tmp_path, monkeypatch, "many", inputs, tmp_path / "out")
    assert p.returncode == 2 and "ABRDF_JAX_READERS" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "out").exists()


GUARD_SCRIPT = r"""
import fcntl, os, sys, time
from pathlib import Path
from abrdf_jax.io._lock import lock_path, output_lock
from abrdf_jax.cli._readers import _orphan_guard

out = Path(sys.argv[1])
guard = sys.argv[2] == "guard"
writer = os.fork()
if writer == 0:  # the command: takes the lock, forks a reader, is killed (no release)
    with output_lock(out):
        if os.fork() == 0:  # the reader
            if guard:
                _orphan_guard(os.getppid())
            time.sleep(3)
            os._exit(0)
        time.sleep(0.3)
        os._exit(0)
os.waitpid(writer, 0)
time.sleep(0.2)
# the writer is gone without releasing: is its lock free for the next writer?
fd = os.open(lock_path(out), os.O_RDWR)
try:
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    print("free")
except OSError:
    print("held")
"""


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_a_reader_does_not_keep_the_output_locked(tmp_path):
    """A forked reader closes the output locks it inherits (``_orphan_guard``): a reader that
    outlives its parent (killed mid-read) must not keep the output locked. The same child
    without the guard keeps it (the check can fail)."""
    import subprocess
    import sys

    (tmp_path / "o").mkdir()
    said = {
        mode: subprocess.run(
            [sys.executable, "-c", GUARD_SCRIPT, str(tmp_path / "o" / "t.npz"), mode],
            capture_output=True,
            text=True,
            timeout=60,
        )
        for mode in ("guard", "none")
    }
    assert said["guard"].stdout.strip() == "free", said["guard"].stderr
    assert said["none"].stdout.strip() == "held", said["none"].stderr


def test_readers_die_with_a_killed_parent(tmp_path):
    """The readers do not wait forever on the pool's queue once their parent is gone."""
    import os
    import subprocess
    import sys
    import time

    script = (
        "import os, time\n"
        "from abrdf_jax.cli._readers import _orphan_guard\n"
        "pid = os.fork()\n"
        "if pid == 0:\n"
        "    child = os.fork()\n"
        "    if child == 0:\n"
        "        _orphan_guard(os.getppid()); time.sleep(30); os._exit(0)\n"
        "    print(child, flush=True); time.sleep(0.5); os._exit(0)\n"  # the parent dies
        "os.waitpid(pid, 0)\n"
    )
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    child = int(p.stdout.split()[0])
    for _ in range(100):  # gone within a few tenths of a second of its parent
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(child, 9)
        raise AssertionError(f"reader {child} outlived its parent")


DYING_SCRIPT = r"""
import os, sys
from pathlib import Path
from abrdf_jax.cli import _readers

def dying_plan(samples, forced, alpha, path, warn, noise=False):
    os._exit(3)  # a reader killed by the system (out of memory, say)

files = sorted(Path(sys.argv[1]).glob("*.csv"))
import contextlib, functools
work = functools.partial(_readers.read_one, dying_plan, None, None, None, True, False)
done = _readers.read_parallel(work, files, 2, lambda: contextlib.nullcontext(type("B", (), {"update": lambda self, n: None})()))
print("none" if done is None else "results")
"""


def test_a_dead_reader_falls_back_to_reading_in_this_process(tmp_path, monkeypatch, capsys):
    """A reader that dies (the system killed it) does not hang the run: the pool reports it,
    and the command line reads the files itself, with a warning, and gives the same tables."""
    import subprocess
    import sys

    inputs = _folder(tmp_path / "in", n=4)
    p = subprocess.run(
        [sys.executable, "-c", DYING_SCRIPT, str(inputs)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.stdout.strip() == "none", p.stderr
    # the command line's reader then reads in its own process, and says so
    from abrdf_jax.cli import _common

    files = sorted(inputs.glob("*.csv"))
    monkeypatch.setattr(_readers, "reader_count", lambda files: 2)
    monkeypatch.setattr(_readers, "read_parallel", lambda *a: None)
    items = _common.read_inputs(files, None, None)
    err = capsys.readouterr().err
    assert "a reader process ended unexpectedly; reading in this process" in err
    monkeypatch.setattr(_readers, "reader_count", lambda files: 1)
    again = _common.read_inputs(files, None, None)
    assert [i.path for i in items] == files == [i.path for i in again]
    for a, b in zip(items, again):
        np.testing.assert_array_equal(np.asarray(a.meas.y), np.asarray(b.meas.y))


IMPORTS_SCRIPT = r"""
import contextlib, functools, sys
from pathlib import Path
from abrdf_jax.cli import _common, _readers

assert "numpy" not in sys.modules  # as the command line before it reads a folder

def imports_of(path):
    before = set(sys.modules)
    what = _readers.read_one(_common.plan, _common.warn_values, None, None, True, True, path)[0]
    return what, sorted(set(sys.modules) - before)

files = sorted(Path(sys.argv[1]).glob("*.csv"))
bar = lambda: contextlib.nullcontext(type("B", (), {"update": lambda self, n: None})())
for what, new in _readers.read_parallel(imports_of, files, 2, bar):
    print(what, " ".join(new) or "-")
"""


def test_readers_inherit_what_they_import(tmp_path):
    """The parent imports what a reader needs (``_readers.PRELOAD``) before it forks: a reader
    imports no module of its own, whatever the capture (iso102, aniso204, jittered angles)."""
    import subprocess
    import sys

    inputs = _folder(tmp_path / "in", n=3)
    for k, budget in enumerate(("aniso204", "iso102")):
        s = aj.simulate_capture(
            materials.get_material("ggx-aniso-metal"), budget=budget, jitter_deg=0.5, seed=k
        )
        io.write_samples_csv(inputs / f"j{k}.csv", s)
    io.write_samples_csv(
        inputs / "a.csv", aj.simulate_capture(materials.get_material("ggx-aniso-metal"))
    )
    p = subprocess.run(
        [sys.executable, "-c", IMPORTS_SCRIPT, str(inputs)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 6, p.stdout
    assert lines == ["ok -"] * 6, p.stdout
