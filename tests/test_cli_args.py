"""Arguments are checked before any work (issue 16): out-of-range and non-finite values, missing
inputs and output folders exit 2 with one line naming the argument and what it accepts, before
any output is written and without importing JAX; a parameter file (``--params``) is checked
field by field, each refusal naming the file and the field."""

import json

import numpy as np
import pytest

from abrdf_jax._errors import InputError
from abrdf_jax.cli import main
from abrdf_jax.io._paramfile import FORMAT, read_params_file
from cli_runner import run_main_cases


@pytest.mark.parametrize("alpha", ["-5", "0", "180", "360", "nan", "inf", "x"])
@pytest.mark.parametrize("command", ["sample", "reconstruct", "fit-self"])
def test_alpha_out_of_range_is_refused(tmp_path, capsys, alpha, command):
    out = tmp_path / "out.csv"
    argv = {
        "sample": ["sample", "ggx-plastic", "-o", str(out)],
        "reconstruct": ["reconstruct", "m.csv", "-o", str(tmp_path / "r.npz")],
        "fit-self": ["fit", "self", "m.csv", "-o", str(tmp_path / "p.json")],
    }[command]
    assert main([*argv, "--alpha", alpha]) == 2
    err = capsys.readouterr().err
    assert "--alpha" in err and "(0, 180)" in err and repr(alpha) in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag", ["--tol", "--noise"])
@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_reconstruct_tolerances_must_be_finite(tmp_path, capsys, flag, value):
    assert main(["reconstruct", "m.csv", "-o", str(tmp_path / "r.npz"), flag, value]) == 2
    err = capsys.readouterr().err
    assert flag in err and "[0, inf)" in err
    assert list(tmp_path.iterdir()) == []


# argv (run in a folder holding m.csv, a valid measurement, and a folder d/), the argument
# argparse names, and what the message says is allowed. Walked from `abrdf-jax CMD --help`.
CASES = [
    (["fit", "self", "m.csv", "-o", "p.json", "--steps", "0"], "--steps", "at least 1"),
    (["fit", "population", "-o", "p.json", "--steps", "x"], "--steps", "an integer"),
    (["fit", "population", "-o", "p.json", "--limit", "0"], "--limit", "at least 1"),
    (["fit", "population", "-o", "p.json", "--data", "nodata"], "--data", "expected a folder"),
    (["fit", "population", "-o", "p.json", "--data", "m.csv"], "--data", "expected a folder"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--lam", "-1"], "--lam", "[0, inf)"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--lam", "nan"], "--lam", "[0, inf)"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--eps", "0"], "--eps", "(0, inf)"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--eps", "inf"], "--eps", "(0, inf)"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--folds", "1"], "--folds", "at least 2"),
    (["prior", "train", "m.csv", "-o", "p.npz", "--components", "0"], "--components", "at least"),
    (["prior", "train", "none.npz", "-o", "p.npz"], "TABLES", "not found"),
    (["prior", "train", "d", "-o", "p.npz"], "TABLES", "expected a file"),
    (["sample", "ggx-plastic", "-o", "s.csv", "--jitter", "nan"], "--jitter", "[0, inf)"),
    (["sample", "ggx-plastic", "-o", "s.csv", "--seed", "-1"], "--seed", "at least 0"),
    (["sample", "ggx-plastic", "-o", "s.csv", "--per-slice", "0"], "--per-slice", "at least 1"),
    (["sample", "ggx-plastic", "-o", "s.csv", "--pairs", "30/95"], "--pairs", "[0, 90)"),
    (["btf", "generate", "-o", "g", "--size", "0"], "--size", "at least 1"),
    (["btf", "generate", "-o", "g", "--size", "4", "--chunk", "0"], "--chunk", "at least 1"),
    (["btf", "generate", "-o", "g", "--size", "4", "--seed", "-1"], "--seed", "at least 0"),
    (["btf", "generate", "-o", "no/g", "--size", "4"], "--output", "no does not exist"),
    (["btf", "reconstruct", "none", "-o", "r"], "MEAS_DIR", "not found"),
    (["btf", "reconstruct", "d", "-o", "no/r"], "--output", "no does not exist"),
    (["btf", "reconstruct", "d", "-o", "r", "--devices", "0"], "--devices", "at least 1"),
    (["btf", "reconstruct", "d", "-o", "r", "--process-id", "-1"], "--process-id", "at least 0"),
    (["btf", "reconstruct", "d", "-o", "r", "--num-processes", "0"], "--num-processes", "least"),
    (["btf", "reconstruct", "d", "-o", "r", "--params", "none.json"], "--params", "not found"),
    (["btf", "import", "none", "-o", "s"], "IMAGES", "not found"),
    (["btf", "import", "d", "-o", "s", "--light-offset", "inf"], "--light-offset", "finite"),
    (["btf", "import", "d", "-o", "s", "--alpha", "0"], "--alpha", "(0, 180)"),
    (["btf", "export", "none", "--zarr", "o.zarr"], "STORE", "not found"),
    (["btf", "export", "m.csv", "--zarr", "o.zarr"], "STORE", "expected a folder"),
    (["btf", "export", "d", "--zarr", "no/o.zarr"], "--zarr", "no does not exist"),
    (["btf", "export", "d", "--exr-dir", "no/e"], "--exr-dir", "no does not exist"),
    (["btf", "evaluate", "d", "none"], "REF", "not found"),
    (["render", "m.csv", "-o", "f.png", "--spp", "0"], "--spp", "[1, 65536]"),
    (["demo", "--materials", "0"], "--materials", "at least 1"),
    (["demo", "-o", "no/f.png"], "--output", "no does not exist"),
    (["reconstruct", "m.csv", "-o", "r.npz", "--params", "none.json"], "--params", "not found"),
    (["reconstruct", "m.csv", "-o", "r.npz", "--params", "d"], "--params", "expected a file"),
    (["suggest", "m.csv", "--samples", "0"], "--samples", "[1, 1000]"),
    (["suggest", "m.csv", "--top", "0"], "--top", "[1, 10000]"),
    (["suggest", "m.csv", "--pairs", "30/95"], "--pairs", "[0, 90)"),
    (["suggest", "m.csv", "--kinds", "both"], "--kinds", "axial and/or diagonal"),
    (["suggest", "none.csv"], "MEAS", "not found"),
]
IDS = [" ".join(argv[:2]) + " " + flag for argv, flag, _ in CASES]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    (tmp_path / "m.csv").write_text("theta_i,phi_i,theta_v,phi_v,r,g,b\n30,15,30,0,0.1,0.2,0.3\n")
    (tmp_path / "d").mkdir()
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("argv, flag, allowed", CASES, ids=IDS)
def test_every_argument_is_checked_while_parsing(workdir, capsys, argv, flag, allowed):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert f"error: argument {flag}" in err[-1].replace("-o/", ""), err  # after the usage
    assert allowed in err[-1], err
    assert sorted(p.name for p in workdir.iterdir()) == ["d", "m.csv"]  # nothing written


def test_argument_errors_import_no_jax(workdir):
    report, err = run_main_cases([(argv, 2) for argv, _, _ in CASES], workdir)
    for (argv, code, jax_loaded), _ in zip(report, CASES):
        assert code == 2, (argv, code, err)
        assert not jax_loaded, f"{argv} imported jax"
    assert "Traceback" not in err


# ---------------------------------------------------------------------------------------------
# Parameter files (`abrdf-jax fit` writes them, `reconstruct --params` reads them)
# ---------------------------------------------------------------------------------------------


def _good() -> dict:
    return {
        "format": FORMAT,
        "config": {
            "budget": "iso102",
            "kernel": "thin_plate_spline",
            "value_space": "logsamples",
            "log_eps": 0.01,
            "pairs": [[30.0, 30.0], [30.0, 75.0], [75.0, 30.0], [75.0, 75.0]],
            "spike_cap": [0.93, 0.5],
        },
        "params": {"alpha_deg": 15.0, "widths": [1.0, 1.0, 1.0, 1.0], "reg": 0.001},
        "fit": {"mode": "self"},
    }


def _set(d, path, value):
    *keys, last = path
    for k in keys:
        d = d[k]
    if value is KeyError:
        del d[last]
    else:
        d[last] = value


NAN = float("nan")
BAD_PARAMS = [  # (where, new value (KeyError: removed), the field the message names)
    (("format",), "abrdf_jax.params/2", "format 'abrdf_jax.params/2'"),
    (("config",), KeyError, "field 'config': missing"),
    (("params",), [1, 2], "field 'params': expected a JSON object, got list"),
    (("params", "reg"), KeyError, "field 'params.reg': missing"),
    (("params", "reg"), -0.1, "field 'params.reg': -0.1, expected a regularisation >= 0"),
    (("params", "reg"), "small", "field 'params.reg': 'small' is not a number"),
    (("params", "reg"), NAN, "field 'params.reg': nan"),
    (
        ("params", "alpha_deg"),
        0,
        "field 'params.alpha_deg': 0, expected a slice offset in (0, 180)",
    ),
    (("params", "alpha_deg"), 180.0, "field 'params.alpha_deg': 180.0"),
    (("params", "alpha_deg"), True, "field 'params.alpha_deg': True is not a number"),
    (("params", "widths"), [1.0, 1.0], "field 'params.widths': expected a list of 4 numbers"),
    (("params", "widths", 2), -1.0, "field 'params.widths[2]': -1.0, expected a width > 0"),
    (("params", "widths", 0), float("inf"), "field 'params.widths[0]': inf"),
    (("config", "kernel"), 3, "field 'config.kernel': 3, expected a name"),
    (("config", "kernel"), "spline", "field 'config': Config.kernel must be one of"),
    (("config", "log_eps"), -1, "field 'config.log_eps': -1, expected > 0"),
    (("config", "pairs", 1), [30, "x"], "field 'config.pairs[1][1]': 'x' is not a number"),
    (("config", "pairs", 1), [30, 95], "field 'config.pairs[1][1]': 95, expected in [0, 90)"),
    (("config", "degree"), 1.5, "field 'config.degree': 1.5, expected an integer >= -1"),
    (("config", "slice_count"), 1, "field 'config.slice_count': 1, expected an integer >= 2"),
    (("config", "colour"), "red", "field 'config': unknown field(s) ['colour']"),
    (("fit",), "yesterday", "field 'fit': expected a JSON object, got str"),
]


def test_a_good_parameter_file_reads_back(tmp_path):
    p = tmp_path / "p.json"
    p.write_text(json.dumps(_good()))
    config, values, fit = read_params_file(p)
    assert config.kernel == "thin_plate_spline" and config.spike_cap == (0.93, 0.5)
    assert values == {"alpha_deg": 15.0, "widths": [1.0] * 4, "reg": 0.001}
    assert fit == {"mode": "self"}


@pytest.mark.parametrize("where, value, message", BAD_PARAMS, ids=[m for *_, m in BAD_PARAMS])
def test_a_bad_parameter_file_names_the_file_and_the_field(tmp_path, where, value, message):
    d = _good()
    _set(d, where, value)
    p = tmp_path / "p.json"
    p.write_text(json.dumps(d))  # NaN and inf as JSON's NaN/Infinity (what Python writes)
    with pytest.raises(InputError) as e:
        read_params_file(p)
    assert str(e.value).startswith(f"{p}: ") and message in str(e.value), str(e.value)


def test_a_bad_parameter_file_fails_before_any_work(workdir):
    """The CLI checks --params before reading the inputs, without JAX, naming the field."""
    d = _good()
    d["params"]["widths"][3] = -2.0
    (workdir / "bad.json").write_text(json.dumps(d))
    (workdir / "broken.json").write_text('{"format": ')
    cases = [
        (["reconstruct", "m.csv", "-o", "r.npz", "--params", "bad.json"], 2),
        (["reconstruct", "m.csv", "-o", "r.npz", "--params", "broken.json"], 2),
        (["btf", "reconstruct", "d", "-o", "r", "--params", "bad.json"], 2),
    ]
    report, err = run_main_cases(cases, workdir)
    assert [r[1] for r in report] == [2, 2, 2] and not any(r[2] for r in report), err
    assert err.count("bad.json: field 'params.widths[3]': -2.0, expected a width > 0") == 2, err
    assert "broken.json:1: not valid JSON" in err
    assert not (workdir / "r.npz").exists() and not (workdir / "r").exists()
    np.testing.assert_equal(sorted(p.name for p in workdir.iterdir()),
                            ["bad.json", "broken.json", "d", "m.csv"])  # fmt: skip
