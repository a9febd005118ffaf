"""A cold folder's operator builds on a second thread (``abrdf_jax.cli._prefetch``).

The command line builds a new layout's operators on a worker thread while the model choice and
the earlier groups run: the RBF blocks at the targets while the held-out entry is built, the
chosen models' operators as soon as a layout group is chosen, the shared second stage of jittered
captures while the direct fits run. Checked here: the builds do run on
the worker, the tables are the same bits as a run whose main thread builds everything, a build
that fails on the worker is built again by the main thread (the run does not notice), and a warm
run starts no worker.
"""

import threading

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import _cache, _host_build, io, materials
from abrdf_jax.cli import _prefetch, main

N = 36  # one layout group of at least OPERATOR_MIN_GROUP (32) inputs


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """``N`` aniso204 captures of one anisotropic material (1 % noise): one layout, one choice."""
    d = tmp_path_factory.mktemp("prefetch") / "in"
    d.mkdir()
    m = materials.get_material("ggx-aniso-metal")
    for k in range(N):
        s = aj.simulate_capture(m, budget="aniso204", noise=0.01, seed=k)
        io.write_samples_csv(d / f"m{k:02d}.csv", s)
    return d


@pytest.fixture
def threads_of(monkeypatch):
    """The thread names that ran each build step (operator builds, target blocks)."""
    seen: dict[str, list[str]] = {"host_matrix": [], "warm_targets": []}
    for name in seen:
        real = getattr(_host_build, name)

        def wrapped(*a, _real=real, _name=name, **k):
            seen[_name].append(threading.current_thread().name)
            return _real(*a, **k)

        monkeypatch.setattr(_host_build, name, wrapped)
    _cache._SHARED.clear()
    _host_build._rbf_at_targets.cache_clear()  # a cold process: the blocks made anew
    yield seen
    _host_build._rbf_at_targets.cache_clear()


def _run(folder, out, cache) -> dict:
    assert main(["reconstruct", str(folder), "-o", str(out), "-q", "--cache-dir", str(cache)]) == 0
    return {p.name: io.read_table(p) for p in sorted(out.glob("*.npz"))}


def _no_prefetch(monkeypatch):
    for name in ("targets", "chosen", "operators", "shared"):
        monkeypatch.setattr(_prefetch.Prefetch, name, lambda self, *a, **k: None)


def test_a_cold_folder_builds_on_the_worker_with_the_same_bits(
    folder, tmp_path, threads_of, monkeypatch
):
    worker = "abrdf-jax-build"
    tables = _run(folder, tmp_path / "out", tmp_path / "cache")
    assert len(tables) == N
    assert threads_of["host_matrix"] and all(
        t.startswith(worker) for t in threads_of["host_matrix"]
    ), threads_of
    assert [t.startswith(worker) for t in threads_of["warm_targets"]] == [True], threads_of
    stored = sorted(p.name for p in (tmp_path / "cache" / "operators").iterdir())
    # the same run with every build on the main thread: the same tables and store entries
    _no_prefetch(monkeypatch)
    _host_build._rbf_at_targets.cache_clear()
    del threads_of["host_matrix"][:]
    again = _run(folder, tmp_path / "again", tmp_path / "cache2")
    assert threads_of["host_matrix"] and all(
        t == threading.main_thread().name for t in threads_of["host_matrix"]
    )
    assert sorted(p.name for p in (tmp_path / "cache2" / "operators").iterdir()) == stored
    assert again.keys() == tables.keys()
    for name, table in tables.items():
        np.testing.assert_array_equal(again[name], table, err_msg=name)


def test_a_build_that_fails_on_the_worker_is_built_by_the_main_thread(
    folder, tmp_path, threads_of, monkeypatch
):
    real, failed = _cache.build_entry, []

    def failing(*a, **k):
        if threading.current_thread() is not threading.main_thread():
            failed.append(1)
            raise RuntimeError("a worker's build fails")
        return real(*a, **k)

    monkeypatch.setattr(_cache, "build_entry", failing)
    tables = _run(folder, tmp_path / "out", tmp_path / "cache")
    assert failed, "nothing was built on the worker"
    assert len(tables) == N
    assert all(t == threading.main_thread().name for t in threads_of["host_matrix"])
    # and the same tables as a run without the worker
    _no_prefetch(monkeypatch)
    again = _run(folder, tmp_path / "again", tmp_path / "cache2")
    for name, table in tables.items():
        np.testing.assert_array_equal(again[name], table, err_msg=name)


def test_a_build_that_needs_jax_is_left_to_the_main_thread(folder, tmp_path, monkeypatch):
    """A singular RBF system (the numpy build gives up) would need the JAX build: the worker
    gives it up before any JAX work; the main thread builds it (here: the numpy build again,
    which does not fail on the main thread)."""
    real, gave_up = _host_build.host_matrix_or_none, []

    def singular_on_the_worker(*a, **k):
        if threading.current_thread() is not threading.main_thread():
            gave_up.append(1)
            return None
        return real(*a, **k)

    monkeypatch.setattr(_host_build, "host_matrix_or_none", singular_on_the_worker)
    _cache._SHARED.clear()
    assert len(_run(folder, tmp_path / "out", tmp_path / "cache")) == N
    assert gave_up


def test_a_warm_folder_starts_no_worker(folder, tmp_path, monkeypatch):
    _run(folder, tmp_path / "out", tmp_path / "cache")
    submitted = []
    monkeypatch.setattr(_prefetch.Prefetch, "_submit", lambda self, *a: submitted.append(a))
    _run(folder, tmp_path / "warm", tmp_path / "cache")
    assert submitted == []


def test_take_and_close_without_builds():
    p = _prefetch.Prefetch(None, print)
    assert p.take(None, None, None) is None
    with p:
        pass
    p.close()  # twice: nothing to stop


@pytest.fixture(scope="module")
def jittered(tmp_path_factory):
    """Six aniso204 captures with 0.5 degrees of encoder error (a layout each: direct fits, and
    the setting's shared second stage), one more as a single file, and a dense capture (60
    samples a slice: a centre layout of its own, whose second stage is shared too)."""
    d = tmp_path_factory.mktemp("jittered")
    (d / "in").mkdir()
    m = materials.get_material("ggx-aniso-metal")
    for k in range(7):
        s = aj.simulate_capture(m, budget="aniso204", noise=0.01, jitter_deg=0.5, seed=40 + k)
        io.write_samples_csv(d / ("one.csv" if k == 6 else f"in/m{k}.csv"), s)
    s = aj.simulate_capture(m, budget="aniso204", noise=0.01, jitter_deg=0.5, per_slice=60, seed=3)
    assert aj.group_slices(s)[0].centre_azimuths is not None  # a dense layout
    io.write_samples_csv(d / "dense.csv", s)
    return d


@pytest.fixture
def two_stage_builds(monkeypatch):
    """The thread of each two-stage (shared second stage) build."""
    seen, real = [], _cache.build_entry

    def counted(*a, two_stage=False, **k):
        if two_stage:
            seen.append(threading.current_thread().name)
        return real(*a, two_stage=two_stage, **k)

    monkeypatch.setattr(_cache, "build_entry", counted)
    _cache._SHARED.clear()
    yield seen
    _cache._SHARED.clear()


@pytest.mark.parametrize("what", ["in", "one.csv", "dense.csv"])
def test_jittered_captures_build_their_shared_stage_on_the_worker(
    jittered, tmp_path, two_stage_builds, monkeypatch, what
):
    """A folder of jittered captures, one jittered file, one dense capture: the second stage
    their models read is built on the worker while the direct fits choose the models, once;
    the same tables as with every build on the main thread."""

    def run(out, cache):
        out = tmp_path / (out if what == "in" else out + ".npz")
        argv = ["reconstruct", str(jittered / what), "-o", str(out), "-q"]
        assert main([*argv, "--cache-dir", str(tmp_path / cache)]) == 0
        paths = sorted(out.glob("*.npz")) if what == "in" else [out]
        return [io.read_table(p) for p in paths]

    tables = run("out", "cache")
    assert len(two_stage_builds) == 1 and two_stage_builds[0].startswith("abrdf-jax-build")
    _no_prefetch(monkeypatch)
    _cache._SHARED.clear()
    again = run("again", "cache2")
    assert two_stage_builds[1:] == [threading.main_thread().name]
    assert len(again) == len(tables) == (6 if what == "in" else 1)
    for a, b in zip(again, tables):
        np.testing.assert_array_equal(a, b)


def test_one_files_choice_makes_the_target_blocks_on_the_worker(
    folder, tmp_path, threads_of, monkeypatch
):
    """One aniso204 file with ``--model auto``, cold: the target blocks are made on the worker
    while the held-out entry is built; the chosen model's build on the main thread waits for
    them and reads them (made once), and the table is the same bits as without the worker."""
    one = folder / "m00.csv"

    def run(out, cache):
        argv = ["reconstruct", str(one), "-o", str(tmp_path / out), "-q"]
        assert main([*argv, "--cache-dir", str(tmp_path / cache)]) == 0
        return io.read_table(tmp_path / out)

    table = run("one.npz", "cache")
    assert [t.startswith("abrdf-jax-build") for t in threads_of["warm_targets"]] == [True]
    assert threads_of["host_matrix"] == [threading.main_thread().name]
    assert _host_build._rbf_at_targets.cache_info().misses == 1
    _no_prefetch(monkeypatch)
    _host_build._rbf_at_targets.cache_clear()
    np.testing.assert_array_equal(run("again.npz", "cache2"), table)


def test_without_a_cache_the_worker_builds_too(folder, tmp_path, threads_of, monkeypatch):
    """``--cache-dir off``: every call builds; the builds run on the worker as well (kept for
    the run), with the same tables as a run without the worker."""

    def run(out):
        argv = ["reconstruct", str(folder), "-o", str(tmp_path / out), "-q", "--cache-dir", "off"]
        assert main(argv) == 0
        return {p.name: io.read_table(p) for p in sorted((tmp_path / out).glob("*.npz"))}

    tables = run("out")
    assert threads_of["host_matrix"] and all(
        t.startswith("abrdf-jax-build") for t in threads_of["host_matrix"]
    ), threads_of
    _no_prefetch(monkeypatch)
    _host_build._rbf_at_targets.cache_clear()
    again = run("again")
    assert again.keys() == tables.keys() and len(tables) == N
    for name, table in tables.items():
        np.testing.assert_array_equal(again[name], table, err_msg=name)
