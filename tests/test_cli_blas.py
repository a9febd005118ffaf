"""``abrdf-jax reconstruct`` computes on one BLAS thread (abrdf_jax.cli._blas): the count is set
inside the block (through the environment before numpy's import) and restored after, a user's
own setting wins, and a folder's tables stay those of a run on more threads within float32
rounding."""

import os
import subprocess
import sys

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials
from abrdf_jax.cli import _blas
from tests.cli_runner import REPO, call_cli


def _counter():
    found = _blas._thread_functions()
    if found is None:
        pytest.skip("numpy's BLAS is not an OpenBLAS this process can reach")
    return found


def test_one_thread_inside_the_block_and_the_count_restored_after(monkeypatch):
    for k in _blas.USER_ENV:
        monkeypatch.delenv(k, raising=False)
    setter, getter = _counter()
    setter(2)
    try:
        with _blas.one_blas_thread() as set_:
            assert set_ and getter() == 1
        assert getter() == 2
        with pytest.raises(RuntimeError), _blas.one_blas_thread():
            raise RuntimeError("an error inside the block")
        assert getter() == 2  # restored on the way out of an error too
    finally:
        setter(2)


@pytest.mark.parametrize("name", _blas.USER_ENV)
def test_a_users_own_thread_count_wins(monkeypatch, name):
    setter, getter = _counter()
    setter(2)
    monkeypatch.setenv(name, "2")
    with _blas.one_blas_thread() as set_:
        assert not set_ and getter() == 2


_FRESH = """
import os, sys
from abrdf_jax.cli import _blas
assert "numpy" not in sys.modules
with _blas.one_blas_thread() as set_:
    inside = os.environ.get("OPENBLAS_NUM_THREADS")
    found = _blas._thread_functions()  # imports numpy: OpenBLAS starts with one thread
    count = None if found is None else found[1]()
after = None if found is None else found[1]()
print(set_, inside, count, "OPENBLAS_NUM_THREADS" in os.environ, after, _blas.cores())
"""


def test_before_numpy_is_imported_openblas_starts_with_one_thread():
    env = {k: v for k, v in os.environ.items() if k not in _blas.USER_ENV}
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run(
        [sys.executable, "-c", _FRESH], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    set_, inside, count, left, after, cores = out
    assert set_ == "True" and inside == "1" and left == "False"
    if count == "None":
        pytest.skip("numpy's BLAS is not an OpenBLAS this process can reach")
    assert count == "1"
    # after: the count OpenBLAS starts with elsewhere (one a core, up to its build's maximum)
    assert after == cores or 1 < int(after) < int(cores)


def _folder_tables(tmp_path, tag):
    out = tmp_path / f"out-{tag}"
    r = call_cli("reconstruct", tmp_path / "in", "-o", out, "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    return {p.name: io.read_table(p) for p in sorted(out.glob("*.npz"))}


def test_a_folders_tables_match_a_run_on_more_threads(tmp_path, monkeypatch):
    setter, _ = _counter()
    (tmp_path / "in").mkdir()
    names = ("ggx-plastic", "lambert-clay", "rough-fabric", "ashikhmin-satin")
    for k in range(12):  # one layout, one batch: the map's product over all twelve at once
        s = aj.simulate_capture(materials.get_material(names[k % 4]), noise=0.01, seed=k)
        io.write_samples_csv(tmp_path / "in" / f"{k:02d}.csv", s)
    for k in _blas.USER_ENV:
        monkeypatch.delenv(k, raising=False)
    setter(2)
    one = _folder_tables(tmp_path, "one")
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's count: left as it is (2)
    two = _folder_tables(tmp_path, "two")
    assert one.keys() == two.keys() and len(one) == 12
    for name in one:
        a, b = one[name].astype(np.float64), two[name].astype(np.float64)
        ulp = np.spacing(np.abs(a).astype(np.float32)).astype(np.float64)
        assert np.all(np.abs(a - b) <= 8 * ulp), name  # a few units in the last place at most
