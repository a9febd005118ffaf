"""The command line's paths that need no numerics import no JAX; its choices come from ``_names``.

``--help`` and every argument or input error that needs no numerics (a malformed CSV, a missing
file, a bad extension, a bad option value) return without importing ``jax``: a fresh interpreter
runs them in turn and reports, after each, whether ``jax`` is in ``sys.modules``.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from abrdf_jax import _names
from abrdf_jax.cli import build_parser
from cli_runner import assert_cli_table, run_main_cases

REPO = Path(__file__).resolve().parents[1]
HEADER = "theta_i,phi_i,theta_v,phi_v,r,g,b"

# argv -> expected exit status; each must leave jax unimported.
NO_JAX_CASES = [
    (["--help"], 0),
    (["--version"], 0),
    (["reconstruct", "--help"], 0),
    (["sample", "--help"], 0),
    (["fit", "population", "--help"], 0),
    (["btf", "reconstruct", "--help"], 0),
    (["render", "--help"], 0),
    (["render", "missing.npz", "-o", "fig.png"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz"], 2),  # a malformed CSV (line 3)
    (["reconstruct", "empty.csv", "-o", "rec.npz"], 2),
    (
        ["reconstruct", "header.csv", "bad.csv", "-o", "out"],
        2,
    ),  # several inputs, each read and checked
    (["reconstruct", "missing.csv", "-o", "rec.npz"], 2),  # a missing file
    (["reconstruct", "bad.csv", "-o", "rec.png"], 2),  # a bad extension
    (
        ["reconstruct", "bad.csv", "-o", "rec.npz", "--preset", "nope"],
        2,
    ),  # a bad option value (argparse)
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--model", "nope"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--tol", "-1"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--preset", "paper", "--model", "iso"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--format", "tiff"], 2),
    (["sample", "table.npz", "-o", "meas.txt"], 2),
    (["sample", "missing.npz", "-o", "meas.csv"], 2),
    (["evaluate", "missing.npz", "other.npz"], 2),
    (["evaluate", "table.tif", "other.npz"], 2),
    (["evaluate", "shape.npz", "shape.npz"], 2),  # a table of the wrong shape
    (["sample", "shape.npz", "-o", "meas.csv"], 2),
    (["fit", "self", "bad.csv", "-o", "p.txt"], 2),
    (["btf", "generate", "-o", "g", "--size", "0"], 2),
    (["demo", "--materials", "0"], 2),
    (["reference", "nope", "-o", "ref.npz"], 2),
    (["reference", "ggx-plastic", "-o", "ref.tif"], 2),
    (["cache", "--help"], 0),
    (["cache", "--cache-dir", "cachedir"], 0),  # shows an empty cache; creates nothing
    (["cache", "--cache-dir", "cachedir", "--clear"], 0),
    (["prior", "--help"], 0),
    (["prior", "train", "--help"], 0),
    (["prior", "info", "--help"], 0),
    (["prior", "default", "--help"], 0),
    (["suggest", "--help"], 0),
    (["suggest", "bad.csv"], 2),  # a malformed CSV: before any numerics
    (["suggest", "missing.csv"], 2),
    (["suggest", "bad.csv", "--pairs", "30/95"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--uncertainty"], 2),  # no variance: auto
    (["prior", "info", "missing.npz"], 2),
    (["prior", "info", "bad.csv"], 2),  # not a prior file
    (["prior", "train", "shape.npz", "-o", "p.txt"], 2),  # a bad output extension
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--model", "prior", "--prior", "bad.csv"], 2),
    (["reconstruct", "bad.csv", "-o", "rec.npz", "--model", "iso", "--prior", "default"], 2),
]


def _run(cases, cwd):
    return run_main_cases(cases, cwd)


def test_help_and_input_errors_import_no_jax(tmp_path):
    (tmp_path / "bad.csv").write_text(
        HEADER + "\n30,15,30,0,0.1,0.2,0.3\n30,0,30,15,0.1,oops,0.3\n"
    )
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "header.csv").write_text(HEADER + "\n")  # no data rows
    np.savez(tmp_path / "shape.npz", abrdf=np.zeros((80, 81, 3), np.float32))
    report, err = _run(NO_JAX_CASES, tmp_path)
    for (argv, want), (_, code, jax_loaded) in zip(NO_JAX_CASES, report):
        assert code == want, (argv, code, err)
        assert not jax_loaded, f"{argv} imported jax"
    assert "bad.csv:3:" in err and "abrdf-jax: error:" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "bad.csv",
        "empty.csv",
        "header.csv",
        "shape.npz",
    ]


def test_prior_info_imports_no_jax(tmp_path, rng):
    from abrdf_jax.prior import save_prior, train_prior

    tables = rng.uniform(0.1, 1.0, (4, 81, 81, 3))
    save_prior(train_prior(tables, k=2), tmp_path / "p.npz")
    report, err = _run([(["prior", "info", "p.npz"], 0)], tmp_path)
    assert report[0][1] == 0, err
    assert not report[0][2], "abrdf-jax prior info imported jax"


def test_model_aniso_runs_in_numpy(tmp_path):
    """``--model aniso`` (filip2012 on the log of the samples: not linear in them) on one
    aniso204 file runs as a two-stage operator entry, the rule per material in numpy
    (``abrdf_jax/_centre_step.py``): no JAX, cold and warm; its table is the float64 pipeline's
    to float32 rounding (measured 2026-12-07: up to 5.5e-6 of the maximum on two materials,
    tests/test_cache.py); the model record says the operator made it."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials

    s = aj.simulate_capture(materials.get_material("ward-brushed-steel"), noise=0.01, seed=2)
    io.write_samples_csv(tmp_path / "m.csv", s)
    argv = ["reconstruct", "m.csv", "-o", "rec.npz", "--model", "aniso", "--cache-dir", "c", "-q"]
    report, err = _run([(argv, 0), (argv, 0)], tmp_path)
    for _, code, jax_loaded in report:
        assert code == 0 and not jax_loaded, (report, err)
    assert len(list((tmp_path / "c" / "operators").glob("*.npz"))) == 1
    record = json.loads((tmp_path / "rec.model.json").read_text())
    assert record["model"] == "aniso" and record["engine"] == "operator"
    config = aj.preset("recommended", "aniso204")
    params = aj.Params.default(config, alpha_deg=record["measurement"]["alpha_deg"])
    assert_cli_table(io.read_table(tmp_path / "rec.npz"), s, config, params, atol=3e-5)


def test_dense_captures_share_one_stored_second_stage(tmp_path):
    """A dense capture (denser RBF centres) runs in two stages in numpy with any affine rule
    (here ``--model iso``'s linear one): no JAX, cold or warm; the second stage does not depend
    on where the samples lie, so a second capture with other angles (another layout, another
    α) reads the stored one and builds nothing; each table is the float64 pipeline's to float32
    rounding."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials

    runs = []
    for k, name in enumerate(("ggx-plastic", "rough-fabric")):
        s = aj.simulate_capture(
            materials.get_material(name), budget="iso102", per_slice=60, jitter_deg=0.3,
            noise=0.01, seed=k,
        )  # fmt: skip
        io.write_samples_csv(tmp_path / f"m{k}.csv", s)
        argv = ["reconstruct", f"m{k}.csv", "-o", f"r{k}.npz", "--model", "iso"]
        runs.append((s, [*argv, "--cache-dir", "c", "-q"]))
    inodes = []
    for _, argv in runs:  # one process each: the second reads the store, not a memory
        report, err = _run([(argv, 0)], tmp_path)
        (_, code, jax_loaded), *_ = report
        assert code == 0 and not jax_loaded, (report, err)
        (entry,) = (tmp_path / "c" / "operators").glob("*.npz")  # one, shared
        inodes.append(entry.stat().st_ino)
    assert inodes[0] == inodes[1]  # read and touched, not written again (a save renames anew)
    config = aj.preset("recommended", "iso102")
    for k, (s, _) in enumerate(runs):
        record = json.loads((tmp_path / f"r{k}.model.json").read_text())
        assert record["engine"] == "operator"
        params = aj.Params.default(config, alpha_deg=record["measurement"]["alpha_deg"])
        meas, _ = aj.group_slices(s, params.alpha_deg)
        assert meas.centre_azimuths is not None  # dense: the denser centre layout
        assert_cli_table(io.read_table(tmp_path / f"r{k}.npz"), s, config, params, atol=1e-4)


def test_a_dense_captures_automatic_choice_imports_no_jax(tmp_path):
    """``--model auto`` on a dense anisotropic capture: the held-out fits in numpy
    (``select._dense_held_out``) and the chosen model's two stages from the store, cold and
    warm; the record names the choice and every candidate's held-out error."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials

    s = aj.simulate_capture(
        materials.get_material("ggx-aniso-metal"), per_slice=60, jitter_deg=0.3, noise=0.01,
        seed=3,
    )  # fmt: skip
    io.write_samples_csv(tmp_path / "m.csv", s)
    argv = ["reconstruct", "m.csv", "-o", "r.npz", "--cache-dir", "c", "-q"]
    report, err = _run([(argv, 0), (argv, 0)], tmp_path)  # cold, then warm
    for _, code, jax_loaded in report:
        assert code == 0 and not jax_loaded, (report, err)
    record = json.loads((tmp_path / "r.model.json").read_text())
    assert record["how"] == "auto" and record["engine"] == "operator"
    errors = {c["name"]: c["held_out_log_rms"] for c in record["candidates"]}
    assert record["model"] in errors and all(np.isfinite(e) for e in errors.values())
    assert errors[record["model"]] <= (1 + record["tol"]) * min(errors.values())  # the rule


def test_a_folder_of_jittered_captures_shares_one_two_stage_map(tmp_path):
    """Each jittered capture has an α of its own, so each is a setting of its own in a folder
    block; their two-stage map (``--model aniso``) does not depend on α, so the block counts it
    once (``_engine.small_build_set``): five captures (five maps' worth if counted per
    setting, over ``OPERATOR_MAX_BUILDS``) get operators, one stored map, no JAX."""
    import abrdf_jax as aj
    from abrdf_jax import _engine, io, materials

    n = 5
    assert n * _engine.TWO_STAGE_BUILD_COST > _engine.OPERATOR_MAX_BUILDS
    (tmp_path / "in").mkdir()
    for k in range(n):
        s = aj.simulate_capture(
            materials.get_material("ggx-aniso-metal"), jitter_deg=0.5, noise=0.01, seed=20 + k
        )
        io.write_samples_csv(tmp_path / "in" / f"m{k}.csv", s)
    argv = ["reconstruct", "in", "-o", "out", "--model", "aniso", "--cache-dir", "c", "-q"]
    report, err = _run([(argv, 0)], tmp_path)
    (_, code, jax_loaded), *_ = report
    assert code == 0 and not jax_loaded, (report, err)
    records = json.loads((tmp_path / "out.model.json").read_text())["inputs"]
    assert len({r["measurement"]["alpha_deg"] for r in records}) == n  # a setting each
    assert all(r["engine"] == "operator" and r["batch"]["small"] for r in records)
    assert len(list((tmp_path / "c" / "operators").glob("*.npz"))) == 1  # one shared map


def test_a_jittered_folder_beyond_the_small_layout_rule_shares_a_second_stage(tmp_path):
    """More jittered captures than ``OPERATOR_MAX_BUILDS`` single-stage builds: a linear rule on
    the log of the samples (``aniso-crossing``) takes the two-stage form, each capture's
    subspaces at the RBF centres then one stored second stage for all of them
    (``_engine.plan_job``), not the pipeline: no JAX, one stored map, and the tables match the
    library's reconstruction (float64 here) to float32 rounding."""
    import abrdf_jax as aj
    from abrdf_jax import _engine, io, materials, select

    n = _engine.OPERATOR_MAX_BUILDS + 1
    (tmp_path / "in").mkdir()
    names = ("ggx-aniso-metal", "ward-brushed-steel")
    for k in range(n):
        s = aj.simulate_capture(
            materials.get_material(names[k % 2]), jitter_deg=0.5, noise=0.01, seed=40 + k
        )
        io.write_samples_csv(tmp_path / "in" / f"m{k:02d}.csv", s)
    argv = ["reconstruct", "in", "-o", "out", "--model", "aniso-crossing", "--cache-dir", "c"]
    report, err = _run([([*argv, "-q"], 0)], tmp_path)
    (_, code, jax_loaded), *_ = report
    assert code == 0 and not jax_loaded, (report, err)
    records = json.loads((tmp_path / "out.model.json").read_text())["inputs"]
    assert len(records) == n and all(r["engine"] == "operator" for r in records)
    shared = [_engine.group_id(("shared", r["batch"]["layout"])) for r in records]
    assert [r["batch"]["group"] for r in records] == shared  # no build a layout (lone ones)
    assert len(list((tmp_path / "c" / "operators").glob("*.npz"))) == 1  # one shared map
    config = select.CANDIDATES["aniso-crossing"].config()
    for r in records[:3]:  # the float64 pipeline's tables to float32 rounding
        name = Path(r["input"]).name
        params = aj.Params.default(config, alpha_deg=r["measurement"]["alpha_deg"])
        table = io.read_table(tmp_path / "out" / name.replace(".csv", ".npz"))
        samples = io.read_samples_csv(tmp_path / "in" / name)
        assert_cli_table(table, samples, config, params, atol=1e-4)


def test_materials_listing_imports_no_jax(tmp_path):
    report, err = _run([(["materials"], 0)], tmp_path)
    assert report[0][1] == 0, err
    assert not report[0][2], "abrdf-jax materials imported jax"


def test_subcommands_import_only_the_shared_module():
    """Arrows point into cli/_common only (which holds cli/_record, the model record,
    cli/_outputs, the output checks and overwrite policy, cli/_caches, --cache-dir,
    cli/_learned, the prior-only model, cli/_prefetch (through cli/_caches), the builds on a
    second thread, cli/_progress, the progress bars and lines,
    cli/_resume, what --resume keeps, cli/_block_plan, a folder block's plans, cli/_readers, the reader processes, cli/_blas, the
    BLAS thread count, cli/_malloc, the allocator's thresholds, and cli/_capture_values, the
    warnings of a capture's values): no subcommand imports another, nor the package's __init__ (checked on
    the source: relative imports inside abrdf_jax/cli)."""
    import ast

    folder = REPO / "abrdf_jax" / "cli"
    for path in sorted(folder.glob("*.py")):
        if path.name in ("__init__.py", "__main__.py"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.ImportFrom) and node.level == 1
            ):  # "from . import x", "from .x import y"
                targets = [node.module] if node.module else [a.name for a in node.names]
                allowed = {
                    "_common.py": {
                        "_record",
                        "_learned",
                        "_outputs",
                        "_args",
                        "_caches",
                        "_progress",
                        "_resume",
                        "_uncertainty",
                        "_readers",
                        "_blas",
                        "_malloc",
                        "_capture_values",
                        "_block_plan",
                    },
                    "_args.py": set(),
                    "_outputs.py": set(),
                    "_caches.py": {"_prefetch"},
                    "_prefetch.py": set(),
                    "_progress.py": set(),
                    "_resume.py": set(),
                    "_record.py": set(),
                    "_learned.py": set(),
                    "_uncertainty.py": {"_outputs"},
                    "_readers.py": {"_progress"},
                    "_blas.py": {"_readers"},
                    "_malloc.py": set(),
                    "_capture_values.py": set(),
                    "_block_plan.py": {"_resume"},
                }.get(path.name, {"_common"})
                assert set(targets) <= allowed, (path.name, targets)


def _actions(parser):
    """Every action of ``parser`` and of its subcommands, recursively: ``(command path, action)``."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for path, a in _actions(sub):
                    yield (name, *path), a
        else:
            yield (), action


def test_choices_come_from_names():
    """Every ``choices=`` list is one of ``abrdf_jax._names``' tuples (or a spelling of one)."""
    names = {v for k, v in vars(_names).items() if k.isupper() and isinstance(v, tuple)}
    derived = {tuple(s.lstrip(".") for s in _names.TABLE_SUFFIXES)}  # --format npz|exr
    seen = []
    for path, action in _actions(build_parser()):
        if action.choices is None:
            continue
        choices = tuple(action.choices)
        seen.append((path, action.dest))
        if (path[-1], action.dest) in {("generate", "reference_dtype"), ("reconstruct", "dtype")}:
            continue  # BTF store dtypes: abrdf_jax.btf's own list (not in _names yet)
        assert choices in names | derived, (path, action.dest, choices)
    assert (("reconstruct",), "preset") in seen and (("btf", "reconstruct"), "backend") in seen


def test_help_defaults_match_the_package():
    """Defaults quoted in help texts are the package's (the parser cannot import them: JAX)."""
    import abrdf_jax as aj
    from abrdf_jax import select

    helps = {(path, a.dest): a.help or "" for path, a in _actions(build_parser())}
    assert f"default {select.TOL:g}" in helps[("reconstruct",), "tol"]
    for path in (("reconstruct",), ("fit", "self"), ("fit", "population"), ("btf", "reconstruct")):
        text = " ".join(helps[path, "preset"].split())
        assert "abrdf_jax.preset(NAME, budget)" in text and all(
            name in text for name in aj.PRESETS
        ), path
    assert "default operator" in " ".join(helps[("btf", "reconstruct"), "preset"].split())


def test_warm_reconstruct_imports_no_jax(tmp_path):
    """A repeat call whose operators are in the operator store runs in numpy (issue 13), and so
    do the cold calls of one file (operators and held-out entries built in numpy): one
    file (``--model auto`` left with one candidate; ``--model auto`` on an aniso204 file, whose
    held-out errors are matrices in the store, ``abrdf_jax.select._held_out_entry``) and a
    folder of one layout; the tables are bit-identical to the cold call's."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials

    iso, aniso = materials.get_material("ggx-plastic"), materials.get_material("ggx-aniso-metal")
    io.write_samples_csv(tmp_path / "iso.csv", aj.sample(iso, aj.Config(budget="iso102")))
    io.write_samples_csv(tmp_path / "aniso.csv", aj.sample(aniso, aj.Config(budget="aniso204")))
    (tmp_path / "dir").mkdir()
    for k in range(33):  # an operator group (>= OPERATOR_MIN_GROUP of one layout)
        s = aj.simulate_capture(iso, budget="iso102", noise=0.01, seed=k)
        io.write_samples_csv(tmp_path / "dir" / f"m{k:02d}.csv", s)
    cache = ["--cache-dir", "cache"]

    def cases(tag):
        return [
            (["reconstruct", "iso.csv", "-o", f"iso-{tag}.npz", *cache], 0),
            (["reconstruct", "aniso.csv", "-o", f"an-{tag}.npz", *cache], 0),
            (["reconstruct", "dir", "-o", f"out-{tag}", "-q", *cache], 0),
        ]

    cold, err = _run(cases("cold"), tmp_path)
    assert [c[1] for c in cold] == [0, 0, 0], err
    # the cold calls built their operators and held-out entries too, in numpy
    # (abrdf_jax._host_build): no JAX either
    assert not cold[0][2] and not cold[1][2], "a cold one-file call imported jax"
    for case in cases("warm"):  # each in a fresh interpreter
        ((argv, code, jax_loaded),), err = _run([case], tmp_path)
        assert code == 0, (argv, err)
        assert not jax_loaded, f"warm {argv} imported jax"
    for a, b in [("iso-cold.npz", "iso-warm.npz"), ("an-cold.npz", "an-warm.npz")] + [
        (f"out-cold/m{k:02d}.npz", f"out-warm/m{k:02d}.npz") for k in range(33)
    ]:
        np.testing.assert_array_equal(io.read_table(tmp_path / a), io.read_table(tmp_path / b))
    record = json.loads((tmp_path / "out-warm.model.json").read_text())
    assert [e["engine"] for e in record["inputs"]] == ["operator"] * 33


def test_one_jittered_file_reads_the_shared_second_stage(tmp_path):
    """One jittered capture per call (a scanner's run, each capture a layout of its own): the
    call reads the setting's shared second stage and scores its candidates by the direct fits
    (``cli/_block_plan.lone_of``), so a second capture of the device builds nothing of its own
    (the store keeps the shared map and the centres' coefficient map: two entries for both);
    no JAX; the cold and the warm call give the same bits; an exact capture (the protocol's)
    still builds its own operator."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials

    for k in range(2):
        s = aj.simulate_capture(
            materials.get_material("ggx-aniso-metal"), jitter_deg=0.5, noise=0.01, seed=7 + k
        )
        io.write_samples_csv(tmp_path / f"j{k}.csv", s)
    cache = ["--cache-dir", "c"]
    cases = [(["reconstruct", f"j{k}.csv", "-o", f"j{k}.npz", *cache], 0) for k in range(2)]
    report, err = _run(
        [*cases, (["reconstruct", "j0.csv", "-o", "again.npz", *cache], 0)], tmp_path
    )
    assert [(code, jax) for _, code, jax in report] == [(0, False)] * 3, err
    for k in range(2):
        rec = json.loads((tmp_path / f"j{k}.model.json").read_text())
        assert rec["engine"] == "operator" and rec["how"] == "auto"
    stored = sorted((tmp_path / "c" / "operators").glob("*.npz"))
    kinds = sorted(json.loads(str(np.load(p)["meta"][()]))["kind"] for p in stored)
    assert kinds == ["centre-map", "rbf"]  # the device's two maps, nothing a capture's own
    assert (tmp_path / "j0.npz").read_bytes() == (tmp_path / "again.npz").read_bytes()
    exact = aj.simulate_capture(materials.get_material("ggx-aniso-metal"), noise=0.01, seed=9)
    io.write_samples_csv(tmp_path / "p.csv", exact)
    report, err = _run([(["reconstruct", "p.csv", "-o", "p.npz", *cache], 0)], tmp_path)
    assert report[0][1] == 0, err
    after = len(list((tmp_path / "c" / "operators").glob("*.npz")))
    assert after == len(stored) + 2  # its own operator and held-out entry


def test_warm_prior_reconstruct_imports_no_jax(tmp_path):
    """``--model prior`` (and ``--model fused``, issue 14) with its entry in the operator store,
    and ``--model auto --prior`` with the held-out entries of every candidate, run in numpy: a prior file and the default prior (found in the cache folder without JAX),
    one file and a folder; the tables are bit-identical to the cold call's."""
    import abrdf_jax as aj
    from abrdf_jax import io, materials
    from abrdf_jax import prior as P
    from abrdf_jax.prior._default import DEFAULT_RECIPE

    tables, names = P.default_training_tables({**DEFAULT_RECIPE, "n": 12})
    P.save_prior(P.train_prior(tables, names, k=6, lam=0.03), tmp_path / "p.npz")
    iso = materials.get_material("ggx-plastic")
    io.write_samples_csv(tmp_path / "iso.csv", aj.sample(iso, aj.Config(budget="iso102")))
    (tmp_path / "dir").mkdir()
    for k in range(3):
        s = aj.simulate_capture(iso, budget="iso102", noise=0.01, seed=k)
        io.write_samples_csv(tmp_path / "dir" / f"m{k}.csv", s)
    common = ["--model", "prior", "--cache-dir", "cache"]
    fused = ["--prior", "p.npz", "--model", "fused", "--cache-dir", "cache"]

    def cases(tag):
        return [
            (["reconstruct", "iso.csv", "-o", f"f-{tag}.npz", "--prior", "p.npz", *common], 0),
            (["reconstruct", "iso.csv", "-o", f"d-{tag}.npz", *common], 0),  # the default prior
            (["reconstruct", "dir", "-o", f"out-{tag}", "-q", "--prior", "p.npz", *common], 0),
            (["reconstruct", "iso.csv", "-o", f"u-{tag}.npz", *fused], 0),
            # --model auto with the prior: held-out entries of the learned models too
            (["reconstruct", "iso.csv", "-o", f"a-{tag}.npz", "--prior", "p.npz", *common[2:]], 0),
        ]

    cold, err = _run(cases("cold"), tmp_path)
    assert [c[1] for c in cold] == [0, 0, 0, 0, 0], err
    for case in cases("warm"):  # each in a fresh interpreter
        ((argv, code, jax_loaded),), err = _run([case], tmp_path)
        assert code == 0, (argv, err)
        assert not jax_loaded, f"warm {argv} imported jax"
    pairs = [
        ("f-cold.npz", "f-warm.npz"),
        ("d-cold.npz", "d-warm.npz"),
        ("u-cold.npz", "u-warm.npz"),
        ("a-cold.npz", "a-warm.npz"),
    ]
    pairs += [(f"out-cold/m{k}.npz", f"out-warm/m{k}.npz") for k in range(3)]
    for a, b in pairs:
        np.testing.assert_array_equal(io.read_table(tmp_path / a), io.read_table(tmp_path / b))


def test_a_quiet_bar_imports_no_tqdm():
    """``-q`` shows no bar, so it costs no ``tqdm`` import: the quiet bar takes the calls the
    command line makes; a shown bar is tqdm's."""
    code = (
        "import sys\n"
        "from abrdf_jax.cli._progress import progress\n"
        "with progress(3, 'read', True) as bar:\n"
        "    bar.update(1); bar.set_description('reconstruct'); bar.update(2)\n"
        "print('tqdm' in sys.modules)\n"
        "progress(3, 'read', False).close()\n"
        "print('tqdm' in sys.modules)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True"]
