"""The ``abrdf-jax`` command line, driven as a user would (subprocesses), plus in-process checks.

Each subprocess pays JAX's start-up and compiles (a few seconds), so their number is kept small:
the workflow and the bad-input cases run the command in a fresh interpreter; the folder mode,
the demo and the reference run ``main`` in this process (``cli_runner.call_cli``: the same exit
status and output).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from abrdf_jax import io
from abrdf_jax.cli import main
from tests.cli_runner import assert_cli_table, call_cli, run_cli


def assert_clean_failure(proc, *names):
    """Non-zero exit, one error message naming the culprit, no traceback."""
    assert proc.returncode != 0, proc.stdout
    assert "Traceback" not in proc.stderr, proc.stderr
    assert "abrdf-jax: error:" in proc.stderr, proc.stderr
    for name in names:
        assert name in proc.stderr, (name, proc.stderr)


def listing(folder: Path):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture(scope="module")
def iso_material():
    from abrdf_jax.cli.demo import choose_materials

    name, _, budget = choose_materials(1)[0]
    assert budget == "iso102"
    return name


def _table(seed, aniso=False):
    """A smooth synthetic ABRDF: coloured Lambertian base plus a broad lobe."""
    from abrdf_jax._grid import ubo_grid

    t, p = np.radians(ubo_grid()[0]), np.radians(ubo_grid()[1])
    w = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    h = w[:, None] + w[None]
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    lobe = np.exp(-(h[..., 0] ** 2 / 0.02 + h[..., 1] ** 2 / (0.02 if not aniso else 0.2)))
    base = np.random.default_rng(seed).uniform(0.1, 0.6, 3) / np.pi
    return ((base + 0.3 * lobe[..., None]) * w[:, 2][:, None, None]).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# The workflow
# ---------------------------------------------------------------------------------------------


def test_sample_reconstruct_evaluate(tmp_path, iso_material):
    proc = run_cli("sample", iso_material, "-o", "meas.csv", "--budget", "iso102", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = (tmp_path / "meas.csv").read_text().strip().splitlines()
    assert lines[0].replace(" ", "") == "theta_i,phi_i,theta_v,phi_v,r,g,b"
    assert len(lines) == 1 + 102
    # Keep a copy of the reference to compare against.
    from abrdf_jax import materials

    io.write_table(
        tmp_path / "ref.npz", materials.dense_table(materials.get_material(iso_material))
    )

    proc = run_cli("reconstruct", "meas.csv", "-o", "rec.npz", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "iso102" in proc.stdout  # the budget is read off the data: diagonal slices only
    rec = io.read_table(tmp_path / "rec.npz")
    assert rec.shape == (81, 81, 3) and np.all(np.isfinite(rec))

    proc = run_cli("evaluate", "rec.npz", "ref.npz", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    for key in ("de76", "de2000", "rmse8", "psnr", "logerr"):
        assert isinstance(doc[key], float) and math.isfinite(doc[key]), doc
    assert 0.0 <= doc["de76"] < 30.0, doc
    assert doc["psnr"] > 5.0, doc


def test_folder_mode_reconstructs_every_file(tmp_path):
    import abrdf_jax as aj

    src = tmp_path / "meas"
    src.mkdir()
    for k, (name, budget) in enumerate((("a", "iso102"), ("b", "iso102"), ("c", "aniso204"))):
        config = aj.Config(budget=budget)
        io.write_samples_csv(
            src / f"{name}.csv", aj.sample(_table(k, budget == "aniso204"), config)
        )
    (src / "notes.txt").write_text("not a measurement")  # ignored: only *.csv are inputs
    proc = call_cli("reconstruct", src, "-o", tmp_path / "out", "--format", "exr", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert listing(tmp_path / "out") == ["a.exr", "b.exr", "c.exr"]
    for name in "abc":
        table = io.read_table(tmp_path / "out" / f"{name}.exr")
        assert table.shape == (81, 81, 3) and np.all(np.isfinite(table)) and table.max() > 0


def test_demo_writes_figure(tmp_path):
    proc = call_cli("demo", "--materials", "2", "-o", "demo.png", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    data = (tmp_path / "demo.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert "dE76" in proc.stdout and "demo.png" in proc.stdout
    assert "iso102" in proc.stdout and "aniso204" in proc.stdout
    assert listing(tmp_path) == ["demo.png"]


def test_reference_writes_the_dense_table_that_evaluate_reads(tmp_path):
    """The README's ``evaluate rec.exr ref.npz`` example needs a reference: ``reference`` writes
    a built-in material's dense table, bit-identical to ``materials.dense_table``."""
    import numpy as np

    from abrdf_jax import io, materials

    proc = call_cli("reference", "ward-brushed-steel", "-o", "ref.npz", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "ref.npz" in proc.stdout
    expected = materials.dense_table("ward-brushed-steel")
    np.testing.assert_array_equal(io.read_table(tmp_path / "ref.npz"), expected)
    proc = call_cli("reference", "ggx-plastic", "-o", "ref.exr", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(
        io.read_table(tmp_path / "ref.exr"), materials.dense_table("ggx-plastic"), rtol=1e-6
    )
    proc = call_cli("evaluate", "ref.npz", "ref.npz", "--json", cwd=tmp_path)
    assert proc.returncode == 0 and '"de76": 0.0' in proc.stdout, proc.stdout + proc.stderr
    proc = call_cli("reference", "no-such", "-o", "x.npz", cwd=tmp_path)
    assert proc.returncode == 2 and "unknown material 'no-such'" in proc.stderr
    assert listing(tmp_path) == ["ref.exr", "ref.npz"]


# ---------------------------------------------------------------------------------------------
# Bad input: a message, no traceback, no output file, existing outputs kept
# ---------------------------------------------------------------------------------------------


def test_missing_input_file(tmp_path):
    proc = run_cli("reconstruct", "nope.csv", "-o", "rec.npz", cwd=tmp_path)
    assert_clean_failure(proc, "nope.csv")
    assert listing(tmp_path) == []


def test_malformed_csv_keeps_existing_output(tmp_path):
    (tmp_path / "bad.csv").write_text(
        "theta_i,phi_i,theta_v,phi_v,r,g,b\n30,15,30,0,0.1,0.1,0.1\n30,0,30,15,0.1,oops,0.1\n"
    )
    (tmp_path / "rec.npz").write_bytes(b"precious")
    proc = run_cli("reconstruct", "bad.csv", "-o", "rec.npz", cwd=tmp_path)
    assert_clean_failure(proc, "bad.csv:3", "oops")
    assert (tmp_path / "rec.npz").read_bytes() == b"precious"
    assert listing(tmp_path) == ["bad.csv", "rec.npz"]


def test_unknown_material_name(tmp_path):
    proc = run_cli("sample", "no-such-material", "-o", "meas.csv", cwd=tmp_path)
    assert_clean_failure(proc, "no-such-material")
    assert listing(tmp_path) == []


def test_output_in_missing_folder(tmp_path):
    io.write_table(tmp_path / "t.npz", _table(0))
    proc = run_cli("sample", "t.npz", "-o", tmp_path / "missing" / "meas.csv", cwd=tmp_path)
    assert_clean_failure(proc, "missing")
    assert listing(tmp_path) == ["t.npz"]


def test_unknown_extension(tmp_path):
    io.write_table(tmp_path / "t.npz", _table(0))
    proc = run_cli("evaluate", "t.npz", "t.tiff", cwd=tmp_path)
    assert_clean_failure(proc, "t.tiff")
    assert listing(tmp_path) == ["t.npz"]


# In-process (no JAX start-up): argument handling that needs no reconstruction.


def test_in_process_errors(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    io.write_table(tmp_path / "t.npz", _table(0))
    (tmp_path / "m.csv").write_text("theta_i,phi_i,theta_v,phi_v,r,g,b\n30,15,30,0,1,1,1\n")
    (tmp_path / "p.json").write_text("{}")  # --params must exist (tests/test_cli_args.py)
    cases = [
        (["reconstruct", "m.csv", "-o", "out.png"], "out.png"),  # unknown table extension
        (["sample", "t.npz", "-o", "meas.txt"], "meas.txt"),  # not a CSV
        (["sample", "t.csv", "-o", "meas.csv"], "t.csv"),  # neither a table nor a material
        (["evaluate", "t.npz", "missing.npz"], "missing.npz"),
        (["reconstruct", "m.csv", "t.npz", "-o", "t.npz"], "t.npz"),  # several inputs need a folder
        (["reconstruct", "m.csv", "-o", "x.npz", "--format", "exr"], "--format"),
        (["demo", "-o", "fig.gif"], "fig.gif"),
        # --preset, --model NAME and --params each fix the model: one at a time
        (
            ["reconstruct", "m.csv", "-o", "x.npz", "--preset", "paper", "--model", "iso"],
            "both fix the model",
        ),
        (
            ["reconstruct", "m.csv", "-o", "x.npz", "--preset", "paper", "--params", "p.json"],
            "both fix the model",
        ),
        (
            ["reconstruct", "m.csv", "-o", "x.npz", "--model", "auto", "--preset", "paper"],
            "--model auto",
        ),
        (
            ["btf", "reconstruct", "m.csv", "-o", "o", "--preset", "paper", "--params", "p.json"],
            "--preset paper",
        ),
    ]
    for argv, name in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("abrdf-jax: error:") and name in err and "Traceback" not in err, (
            argv,
            err,
        )
    assert listing(tmp_path) == ["m.csv", "p.json", "t.npz"]
    # A usage error is argparse's (exit 2); -v shows tracebacks.
    assert main(["reconstruct", "m.csv"]) == 2
    assert "-o/--output" in capsys.readouterr().err
    assert main(["-v", "evaluate", "t.npz", "missing.npz"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_version_help_and_materials(capsys):
    assert main(["--version"]) == 0
    assert "abrdf-jax" in capsys.readouterr().out
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("reconstruct", "sample", "evaluate", "demo", "materials"):
        assert command in out
    assert main(["materials"]) == 0
    from abrdf_jax import materials

    out = capsys.readouterr().out
    for name in materials.material_names():
        assert name in out


def test_evaluate_table_output(tmp_path, capsys):
    ref = _table(1)
    io.write_table(tmp_path / "ref.npz", ref)
    io.write_table(tmp_path / "rec.exr", ref * 1.1)
    assert main(["evaluate", str(tmp_path / "rec.exr"), str(tmp_path / "ref.npz")]) == 0
    out = capsys.readouterr().out
    for label in ("dE76", "dE2000", "RMSE8", "PSNR", "LogErr"):
        assert label in out
    # The identical table: PSNR is infinite, JSON reports it as null.
    assert main(["evaluate", str(tmp_path / "ref.npz"), str(tmp_path / "ref.npz"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["psnr"] is None and doc["de76"] == 0.0


def test_internal_errors_exit_1_with_traceback(tmp_path, capsys, monkeypatch):
    """A bug (any exception that is not bad input) is not blamed on the input: exit 1, traceback,
    and a line asking to report it; an OSError naming a file is bad input (one line, exit 2)."""
    import abrdf_jax as aj
    from abrdf_jax.cli._common import version

    monkeypatch.chdir(tmp_path)
    io.write_table(tmp_path / "t.npz", _table(0))

    def bug(*args, **kwargs):
        raise ValueError("a bug")

    monkeypatch.setattr(aj, "sample", bug)
    assert main(["sample", "t.npz", "-o", "m.csv"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ValueError: a bug" in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("abrdf-jax: internal error (ValueError: a bug)") and "report" in last, (
        last
    )
    assert f"abrdf-jax {version()}" in last
    assert listing(tmp_path) == ["t.npz"]

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied", "m.csv")

    monkeypatch.setattr(aj, "sample", denied)
    assert main(["sample", "t.npz", "-o", "m.csv"]) == 2
    assert capsys.readouterr().err == "abrdf-jax: error: m.csv: Permission denied\n"


def test_preset_fixes_the_model(tmp_path, capsys, iso_material):
    """--preset NAME reconstructs with abrdf_jax.preset(NAME, budget); the record names the model."""
    import abrdf_jax as aj

    meas = tmp_path / "m.csv"
    assert main(["sample", iso_material, "-o", str(meas), "--budget", "iso102"]) == 0
    samples = io.read_samples_csv(meas)
    for preset, model in (("operator", "operator"), ("recommended", "iso")):
        out = tmp_path / f"{preset}.npz"
        assert main(["reconstruct", str(meas), "-o", str(out), "--preset", preset]) == 0
        doc = json.loads((tmp_path / f"{preset}.model.json").read_text())
        assert (
            doc["how"] == "preset"
            and doc["model"] == model
            and doc["reason"].startswith(f"--preset {preset}:")
        )
        config = aj.preset(preset, "iso102")
        assert_cli_table(io.read_table(out), samples, config, aj.Params.default(config))
    assert "model: operator (preset)" in capsys.readouterr().out
