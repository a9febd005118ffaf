"""``abrdf-jax render`` (issue 15): figures of small Mitsuba renders (32 px, 4 spp, scalar_rgb),
a zero ΔE76 map against an identical reference, and the one-line errors (exit 2, no output)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from cli_runner import REPO, call_cli

pytest.importorskip("mitsuba")

SMALL = ["--size", "32", "--spp", "4"]


def _png_size(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.size


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """A constant table and ``abrdf-jax reference ggx-aniso-metal``'s, in one folder."""
    d = tmp_path_factory.mktemp("render")
    np.savez(d / "const.npz", abrdf=np.full((81, 81, 3), 0.05, np.float32))
    np.savez(d / "shape.npz", abrdf=np.zeros((80, 81, 3), np.float32))
    proc = call_cli("reference", "ggx-aniso-metal", "-o", "ref.npz", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d


def test_render_a_constant_table(tables):
    proc = call_cli("render", "const.npz", "-o", "const.png", *SMALL, cwd=tables)
    assert proc.returncode == 0, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.startswith("abrdf-jax: rendered")]
    assert len(lines) == 2  # sphere and cylinder, env light, no reference
    assert "sphere, env light, table: 32 x 32 px, 4 spp, scalar_rgb" in lines[0]
    assert proc.stdout.strip().endswith("figure: const.png")
    # scene_figure's layout at 100 dpi: one view per row, 2 rows (4.5 in wide at least,
    # 2 x (1.7 + 0.45) + 0.25 + 0.75 in high)
    assert _png_size(tables / "const.png") == (450, 530)


def test_identical_reference_gives_a_zero_map_and_quiet_is_quiet(tables):
    args = ["render", "ref.npz", "ref.npz", "-o", "same.png", *SMALL, "--light", "both", "-q"]
    proc = call_cli(*args, cwd=tables)
    assert proc.returncode == 0, proc.stderr
    assert "rendered" not in proc.stderr
    stats = [x for x in proc.stdout.splitlines() if "ΔE76 mean" in x]
    assert [x.split(":")[0] for x in stats] == [
        "sphere, env",
        "sphere, point",
        "cylinder, env",
        "cylinder, point",
    ]
    assert all("mean 0.00, 95th percentile 0.00, max 0.00" in x for x in stats), stats
    # two views (env, point) of three panels and a colour bar per row: 0.95 + 1.7 x 6.06 in
    assert _png_size(tables / "same.png") == (1125, 530)


def test_render_views_map_is_exactly_zero_only_for_the_same_table():
    from abrdf_jax import materials, render

    ref = materials.dense_table("ggx-aniso-metal")
    other = materials.dense_table("ggx-plastic")
    kw = dict(shapes=("cylinder",), lights=("point",), size=16, spp=2)
    (same,) = render.render_views(ref, ref, **kw)
    (diff,) = render.render_views(other, ref, **kw)
    assert same.rec.shape == (16, 16, 4) and 0 < same.rec[..., 3].mean() < 1
    assert np.all(render.view_error(same)["de76_map"] == 0.0)
    err = render.view_error(diff)
    assert err["de76_mean"] > 1.0 and err["de76_map"][same.rec[..., 3] == 0].max() == 0.0


_SCRIPT = r"""
import json, sys
from abrdf_jax.cli import main
report = []
for argv in json.loads(sys.argv[1]):
    report.append([argv, main(argv), "jax" in sys.modules])
print(json.dumps(report))
"""

BAD = [
    (["render", "const.npz", "-o", "x.png", "--spp", "0"], "--spp must be in [1, 65536], got 0"),
    (["render", "const.npz", "-o", "x.png", "--spp", "many"], "--spp must be an integer"),
    (["render", "const.npz", "-o", "x.png", "--size", "4"], "--size must be in [8, 2048], got 4"),
    (["render", "missing.npz", "-o", "x.png"], "missing.npz: file not found"),
    (["render", "const.npz", "missing.npz", "-o", "x.png"], "missing.npz: file not found"),
    (["render", "shape.npz", "-o", "x.png"], "shape.npz"),
    (["render", "const.npz", "-o", "x.tif"], "x.tif: unknown figure extension"),
    (["render", "const.npz", "-o", "x.png", "--variant", "nope"], "--variant"),
    (["render", "const.npz", "-o", "x.png", "--light", "sun"], "--light"),
]


def test_bad_arguments_and_files_exit_2_without_output_or_jax(tables):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for argv, message in BAD:  # one interpreter per case: stderr is the case's own
        proc = subprocess.run(
            [sys.executable, "-c", _SCRIPT, json.dumps([argv])],
            cwd=tables,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        (report,) = json.loads(proc.stdout.strip().splitlines()[-1])
        assert report[1] == 2, (argv, proc.stderr)
        assert not report[2], f"{argv} imported jax"
        assert message in proc.stderr and "Traceback" not in proc.stderr, (argv, proc.stderr)
    assert not list(tables.glob("x.*")) and not list(tables.glob(".x.*"))


def test_missing_mitsuba_names_the_extra(tables):
    code = (
        "import sys; sys.modules['mitsuba'] = None; sys.modules['drjit'] = None\n"
        "from abrdf_jax.cli import main\n"
        "sys.exit(main(['render', 'const.npz', '-o', 'nomitsuba.png', '--size', '8']))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tables,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    errors = [x for x in proc.stderr.splitlines() if "error" in x]
    assert errors == [
        "abrdf-jax: error: rendering needs Mitsuba 3 (pip install 'abrdf_jax[render]')"
    ], proc.stderr
    assert not (tables / "nomitsuba.png").exists()


def test_newest_libllvm_is_chosen(monkeypatch):
    from abrdf_jax.render import _variants

    found = {
        _variants.LLVM_GLOBS[0]: ["/x/libLLVM-15.so.1", "/x/libLLVM-19.so", "/x/libLLVM.so.19.1"],
        _variants.LLVM_GLOBS[1]: ["/y/llvm-14/lib/libLLVM-14.so"],
    }
    monkeypatch.setattr(_variants.glob, "glob", lambda pattern: found.get(pattern, []))
    monkeypatch.setattr(_variants.os.path, "isfile", lambda path: True)
    assert _variants.llvm_library() == "/x/libLLVM-19.so"
    monkeypatch.setattr(_variants.glob, "glob", lambda pattern: [])
    assert _variants.llvm_library() is None


def test_a_variant_whose_test_render_aborts_is_refused_in_one_line(monkeypatch):
    """A libLLVM that Dr.Jit cannot compile with aborts the process (LLVM 15: SIGABRT): the
    child's death becomes the refusal's reason, and the parent lives on."""
    from abrdf_jax import InputError
    from abrdf_jax.render import _variants

    monkeypatch.setattr(
        _variants, "_PROBE", "import os; print('LLVM ERROR: Cannot select'); os.abort()"
    )
    monkeypatch.setattr(_variants, "probe", _variants.probe.__wrapped__)  # no cached answer
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", os.environ.get("DRJIT_LIBLLVM_PATH", ""))  # restored
    reason = _variants.probe("llvm_ad_rgb")
    assert reason.startswith("a test render failed (exit status -6)") and "LLVM ERROR" in reason
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    with pytest.raises(InputError, match=r"--variant llvm_ad_rgb does not work here: a test"):
        _variants.use_variant("llvm_ad_rgb")
    assert mi.variant() == "scalar_rgb"
