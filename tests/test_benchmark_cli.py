"""``python -m benchmarks.cli``'s parts, without running the benchmark: the scipy peer's command line
(``benchmarks/scipy_cli.py``) gives the oracle's table and imports no JAX; the argument parsing,
the peer's time scaling and the target checks of issue 13 work on made-up results."""

import json
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials
from benchmarks import cli, scipy_cli
from benchmarks._cli_report import (
    chart_rows,
    check_targets,
    derive,
    markdown,
    pass_fail_lines,
    write_reports,
)
from benchmarks.scipy_peer import scipy_kwargs
from tests.cli_runner import run_module
from tests.scipy_oracle import reconstruct_scipy

REPO = cli.REPO


def _peer(*args, timeout=300):
    return run_module("benchmarks.scipy_cli", *args, cwd=REPO, timeout=timeout)


@pytest.mark.parametrize("budget", ["iso102", "aniso204"])
def test_peer_defaults_are_the_paper_setting(budget):
    config = aj.Config(budget=budget)  # the benchmarks run in float32 (the tests in float64)
    want = scipy_kwargs(config, aj.Params.default(config, dtype=jnp.float32))
    got = scipy_cli.PAPER_KWARGS
    assert got.keys() == want.keys()
    for k, v in want.items():
        if k == "widths":
            assert tuple(map(float, v)) == got[k]
        else:
            assert got[k] == v, k


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """One aniso204 capture of an analytic material, written as a measurement CSV file."""
    folder = tmp_path_factory.mktemp("peer")
    samples = aj.simulate_capture(
        materials.get_material(cli.ANISO_MATERIAL), budget="aniso204", noise=0.01, seed=3
    )
    io.write_samples_csv(folder / "m.csv", samples)
    return folder, samples


def test_peer_cli_table_is_the_oracle(capture):
    folder, s = capture
    out = folder / "m.npz"
    proc = _peer(folder / "m.csv", "-o", out)
    assert proc.returncode == 0, proc.stderr
    got = np.load(out)["abrdf"]
    want = reconstruct_scipy(
        s.theta_i, s.phi_i, s.theta_v, s.phi_v, s.rgb, **scipy_cli.PAPER_KWARGS
    )
    assert got.shape == (81, 81, 3) and got.dtype == np.float64
    np.testing.assert_array_equal(got, want)
    # the package reads it too (as float32, its table dtype)
    np.testing.assert_array_equal(io.read_table(out), want.astype(np.float32))


def test_peer_cli_folder_limit_and_bad_input(capture, tmp_path):
    folder, _ = capture
    for i in range(3):
        (tmp_path / "in").mkdir(exist_ok=True)
        (tmp_path / "in" / f"{i}.csv").write_bytes((folder / "m.csv").read_bytes())
    proc = _peer(tmp_path / "in", "-o", tmp_path / "out", "--limit", 2)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["0.npz", "1.npz"]
    bad = cli.write_bad_csv(tmp_path / "bad.csv")
    proc = _peer(bad, "-o", tmp_path / "bad.npz")
    assert proc.returncode == 2 and "error:" in proc.stderr and "bad.csv" in proc.stderr
    assert not (tmp_path / "bad.npz").exists()


def test_peer_cli_imports_no_jax():
    code = (
        "import sys, benchmarks.scipy_cli as m; m.parse_args(['x.csv', '-o', 'y.npz']); "
        "bad = [k for k in sys.modules if k.split('.')[0] in ('jax', 'jaxlib', 'abrdf_jax')]; "
        "assert not bad, bad"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_parse_args_modes():
    full = cli.parse_args([])
    assert full.mode == "full" and full.sizes == cli.SIZES["full"]
    assert full.sizes == {
        "iso_small": 100,
        "iso_large": 1000,
        "aniso_large": 1000,
        "iso_jitter": 200,
        "aniso_jitter": 200,
        "aniso_few": 8,
        "dense_few": 16,
        "iso_parallel": 40,
    }
    assert (full.peer_limit, full.repeats) == (cli.PEER_LIMIT["full"], cli.REPEATS["full"])
    quick = cli.parse_args(["--quick", "--peer-limit", "5", "--repeats", "2"])
    assert quick.mode == "quick" and quick.sizes == cli.SIZES["quick"]
    assert (quick.peer_limit, quick.repeats) == (5, 2)
    with pytest.raises(SystemExit):
        cli.parse_args(["--peer-limit", "1"])
    assert full.folder_repeats == cli.FOLDER_REPEATS["full"] and quick.folder_repeats == 1
    assert cli.parse_args(["--folder-repeats", "5"]).folder_repeats == 5
    with pytest.raises(SystemExit):
        cli.parse_args(["--folder-repeats", "0"])


def test_median_run_of_folder_calls():
    calls = [
        _run(3.0, files=1000, rss=150.0) | {"expected_exit": 0, "shown": "a"},
        _run(1.0, files=1000, rss=300.0) | {"expected_exit": 0, "shown": "b"},
        _run(2.0, files=1000, rss=100.0) | {"expected_exit": 0, "shown": "c"},
    ]
    row = cli.median_run(calls)
    assert row["seconds"] == 2.0 and row["shown"] == "c" and row["all_seconds"] == [3.0, 1.0, 2.0]
    assert row["repeats"] == 3 and row["peak_rss_mib"] == 300.0 and row["ok"]
    assert row["exit_code"] == 0
    calls[0] |= {"ok": False, "exit_code": 2}  # one call failing fails the row
    row = cli.median_run(calls)
    assert not row["ok"] and row["exit_code"] == 2
    even = cli.median_run(calls[1:])
    assert even["seconds"] == 1.5 and even["shown"] == "b"  # two: their mean, the lower's row


def test_scale_peer():
    run = {"files": 10, "seconds": 5.5, "ok": True}
    s = cli.scale_peer(run, 1000, startup=0.5)
    assert s["files"] == 1000 and s["scaled_from"] == 10 and s["measured_seconds"] == 5.5
    assert s["seconds"] == pytest.approx(0.5 + 5.0 * 100)
    assert cli.scale_peer(run, 10, startup=0.5) is run  # measured whole: not scaled


def _run(seconds, files=1, rss=200.0, ok=True, exit_code=0):
    return {
        "seconds": seconds,
        "files": files,
        "peak_rss_mib": rss,
        "ok": ok,
        "exit_code": exit_code,
        "shown": "cmd",
        "repeats": 1,
    }


def _fake_runs(**package_seconds):
    """Results of every run the benchmark makes; ``package_seconds`` overrides package times."""
    peer1 = _run(0.7)
    s = {
        "help": 0.1,
        "input_error": 0.2,
        "iso1_cold": 1.5,
        "iso1_warm": 0.5,
        "aniso1_auto_cold": 3.0,
        "aniso1_auto_warm": 1.0,
        "aniso1_aniso_cold": 2.0,
        "aniso1_aniso_warm": 0.6,
        "dense1_auto_cold": 5.0,
        "dense1_auto_warm": 0.5,
        "dense1_aniso_cold": 3.5,
        "dense1_aniso_warm": 0.3,
        "iso_large": 1.5,
        "iso_large_warm": 1.0,
        "aniso_large": 3.0,
        "aniso_large_warm": 2.0,
    } | package_seconds
    runs = {k: {"what": k, "files": 1, "package": _run(v), "peer": peer1} for k, v in s.items()}
    for key in ("iso_large", "aniso_large"):
        peer = _run(337.0, 1000)  # one peer run: a cold and a warm row of the package
        for k in (key, f"{key}_warm"):
            runs[k] = {"what": k, "files": 1000, "package": _run(s[k], 1000, rss=800.0)}
            runs[k]["peer"] = peer
    derive(runs)
    return runs


def test_targets_pass_and_fail():
    runs = _fake_runs()
    targets = check_targets(runs)
    assert len(targets) == 15
    assert all(t["pass"] for t in targets), [t for t in targets if not t["pass"]]
    assert runs["iso_large"]["ratio"] == pytest.approx(337.0 / 1.5)
    assert runs["iso_large"]["package"]["files_per_s"] == pytest.approx(1000 / 1.5)
    assert "1000 iso102 files" in targets[4]["target"] and "cold" in targets[4]["target"]

    runs = _fake_runs(
        help=0.4, iso1_warm=0.8, iso_large=2.0, aniso1_auto_warm=1.3, dense1_auto_warm=0.7
    )
    runs["aniso_large"]["package"]["peak_rss_mib"] = 1500.0
    runs["input_error"]["package"]["ok"] = False
    del runs["aniso1_aniso_cold"]
    by = {t["target"]: t for t in check_targets(runs)}
    failed = sorted(t for t, v in by.items() if not v["pass"])
    assert failed == sorted(
        [
            "`abrdf-jax --help` <= 0.3 s",
            "one iso102 file, warm cache: ratio to the peer >= 1",
            "1000 iso102 files, one call, cold cache: ratio per file >= 200",
            "peak RSS of the 1000-file aniso204 run <= 1 GiB (MiB)",
            "one aniso204 file, warm: --model auto s / --model aniso s <= 2",
            "one aniso204 file, cold: --model auto s / --model aniso s <= 2",
            "one dense aniso204 capture, warm (beyond the issue's protocol file): "
            "--model auto s / --model aniso s <= 2",
            "every run exits as expected and writes every output (runs failing)",
        ]
    )
    assert by["one aniso204 file, cold: --model auto s / --model aniso s <= 2"]["value"] is None
    assert by["every run exits as expected and writes every output (runs failing)"]["failed"] == [
        "input_error/package"
    ]


def _fake_payload():
    runs = _fake_runs()
    return {
        "mode": "quick",
        "machine": {"processor": "x86_64", "cpu_count": 2, "platform": "Linux", "date": "now"},
        "commands": {"benchmark": "python -m benchmarks.cli --quick"},
        "load_average_before": [1.0, 1.0, 1.0],
        "load_average_after": [2.0, 1.0, 1.0],
        "seconds": 12.0,
        "inputs": {"what": "Inputs."},
        "caches": "Caches.",
        "peer_note": "Peer.",
        "runs": runs,
        "targets": check_targets(runs),
    }


def test_markdown_of_fake_results():
    payload = _fake_payload()
    runs = payload["runs"]
    md = markdown(payload)
    assert md.count("| package |") == len(runs)
    assert md.count("| peer |") == 3  # the one-file peer run is shared: one row
    assert "FAIL" not in md and md.count("PASS") == 15
    assert len(pass_fail_lines(payload["targets"])) == 15


def test_chart_of_fake_results(tmp_path):
    """The chart's rows pair each cold call with its warm one (their ratios), and the report
    writes the chart beside the table, which shows it."""
    payload = _fake_payload()
    for key, entry in payload["runs"].items():  # the benchmark's labels
        for state in ("cold", "warm"):
            if key.endswith("_" + state):
                entry["what"] = f"{key.removesuffix('_' + state)}, {state} cache"
    rows = {label: tuple(values) for label, *values in chart_rows(payload["runs"])}
    for key, entry in payload["runs"].items():
        label = entry["what"].removesuffix(", cold cache").removesuffix(", warm cache")
        assert entry["ratio"] in rows[label], (key, rows[label])
    assert any(None not in r[:2] for r in rows.values()), rows  # a cold and a warm call paired
    assert len(rows) < len(payload["runs"])
    md = write_reports(payload, tmp_path, "_t")
    assert (tmp_path / "cli_t.png").stat().st_size > 0 and "](cli_t.png)" in md
    assert (tmp_path / "cli_t.md").read_text() == md


def test_timed_child_reports_the_command(tmp_path):
    """The launcher of every timed command: its exit code, seconds and its own peak RSS."""
    result = tmp_path / "r.json"
    code = "import sys; sys.exit(3)"
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks._timed_child", result, sys.executable, "-c", code],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    got = json.loads(result.read_text())
    assert got["exit_code"] == 3 and got["seconds"] > 0
    assert 0 < got["peak_rss_mib"] < 200  # a bare interpreter, not this process's RSS


def test_floors_are_measured_and_shown(tmp_path):
    """The machine's floors of a folder run: tables written (and removed again), CSV files
    parsed, both shown in the report's header."""
    from benchmarks.cli import floors, write_inputs
    from abrdf_jax import materials

    models = {n: materials.get_material(n) for n in materials.material_names()[:2]}
    write_inputs(tmp_path / "iso_large", "iso102", 3, models)
    f = floors(tmp_path, 3, lambda s: None)
    assert f["files"] == 3 and f["write_tables_s"] > 0 and f["parse_csv_s"] > 0
    assert not (tmp_path / "floor-writes").exists()
    from benchmarks._cli_report import _floors

    text = "\n".join(_floors(f))
    assert "writing 3 tables took" in text and "parsing 3 iso102 CSV files" in text
    assert _floors(None) == []


def test_parallel_calls_run_each_file_and_report_a_failure(tmp_path):
    from benchmarks import _parallel_calls as pc

    (tmp_path / "in").mkdir()
    for name in ("b", "a", "c"):
        (tmp_path / "in" / f"{name}.csv").write_text(name)
    copy = [sys.executable, "-c", "import shutil, sys; shutil.copy(sys.argv[1], sys.argv[2])"]
    cmds = pc.commands(2, tmp_path / "in", tmp_path / "out", [*copy, "{in}", "{out}"])
    assert [c[-2:] for c in cmds] == [
        [str(tmp_path / "in" / f"{n}.csv"), str(tmp_path / "out" / f"{n}.npz")] for n in "ab"
    ]
    code = pc.main(["2", "3", str(tmp_path / "in"), str(tmp_path / "out"), *copy, "{in}", "{out}"])
    assert code == 0 and sorted(p.read_text() for p in (tmp_path / "out").iterdir()) == list("abc")
    fail = [sys.executable, "-c", "import sys; sys.exit(3 if 'b' in sys.argv[1] else 0)", "{in}"]
    assert pc.run(pc.commands(3, tmp_path / "in", tmp_path / "out", fail), 2) == 3
