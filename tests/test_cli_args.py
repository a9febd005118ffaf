"""Arguments are checked before any work (issue 16): out-of-range and non-finite values exit 2
with the allowed range in the message, before any output is written."""

import pytest

from abrdf_jax.cli import main


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
