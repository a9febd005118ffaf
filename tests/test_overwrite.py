"""The one overwrite policy of every writing command (issue 16; docs/stability.md, "Overwriting
outputs"): an output file that exists is replaced, atomically, with one line "replacing FILE";
an output folder or store of the same settings is resumed or redone, one of other settings is
refused (exit 2, naming --overwrite, the output untouched) and replaced with --overwrite."""

import importlib.util
import json

import numpy as np
import pytest

from abrdf_jax import io
from abrdf_jax.cli import build_parser
from abrdf_jax.cli._common import OVERWRITE_POLICY
from cli_runner import call_cli

WRITERS = [
    ("sample",),
    ("reconstruct",),
    ("reference",),
    ("render",),
    ("demo",),
    ("fit", "self"),
    ("fit", "population"),
    ("prior", "train"),
    ("prior", "default"),
    ("btf", "generate"),
    ("btf", "reconstruct"),
    ("btf", "import"),
    ("btf", "export"),
    ("btf", "evaluate"),
]


def _sub(parser, path):
    import argparse

    for name in path:
        (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        parser = action.choices[name]
    return parser


@pytest.mark.parametrize("path", WRITERS, ids=" ".join)
def test_every_writer_states_the_policy_in_its_help(path):
    text = " ".join(_sub(build_parser(), path).format_help().split())
    assert " ".join(OVERWRITE_POLICY.split()) in text


def test_readers_do_not_claim_to_write():
    for path in [("evaluate",), ("materials",), ("prior", "info"), ("suggest",)]:
        assert OVERWRITE_POLICY.split()[0] not in _sub(build_parser(), path).format_help()


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with one measurement (the README's ``sample ggx-plastic -o meas.csv``, twice)."""
    d = tmp_path_factory.mktemp("overwrite")
    first = call_cli("sample", "ggx-plastic", "-o", "meas.csv", cwd=d)
    assert first.returncode == 0 and "replacing" not in first.stderr, first.stderr
    again = call_cli("sample", "ggx-plastic", "-o", "meas.csv", "--noise", "0.02", cwd=d)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("replacing meas.csv") == 1
    assert len(io.read_sample_columns(d / "meas.csv")) == 102
    return d


def _replaced_twice(work, name, *argv):
    """Run ``argv`` twice into ``name``: the second says it replaces it, and does."""
    first = call_cli(*argv, cwd=work)
    assert first.returncode == 0, first.stderr
    (work / name).write_bytes(b"stale")  # the rerun must replace this, whatever it is
    again = call_cli(*argv, cwd=work)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count(f"replacing {name}") == 1, again.stderr
    assert (work / name).read_bytes() != b"stale"
    assert not [p for p in work.iterdir() if p.name.endswith(".tmp")]


def test_single_file_reconstruct_reruns_with_other_flags(work):
    a = call_cli("reconstruct", "meas.csv", "-o", "rec.npz", "--model", "iso", cwd=work)
    assert a.returncode == 0 and "replacing" not in a.stderr, a.stderr
    iso = io.read_table(work / "rec.npz")
    b = call_cli("reconstruct", "meas.csv", "-o", "rec.npz", "--preset", "paper", cwd=work)
    assert b.returncode == 0, b.stderr
    assert b.stderr.count("replacing rec.npz") == 1
    assert not np.array_equal(io.read_table(work / "rec.npz"), iso)  # the paper model's table
    assert json.loads((work / "rec.model.json").read_text())["model"] == "paper"
    bad = call_cli("reconstruct", "meas.csv", "-o", "rec.npz", "--overwrite", cwd=work)
    assert bad.returncode == 2 and "--overwrite is for an output folder" in bad.stderr


def test_reference_and_prior_default_replace(work):
    _replaced_twice(work, "ref.npz", "reference", "ggx-plastic", "-o", "ref.npz")
    _replaced_twice(work, "prior.npz", "prior", "default", "-o", "prior.npz")


@pytest.mark.skipif(importlib.util.find_spec("mitsuba") is None, reason="render extra")
def test_render_replaces(work):
    assert call_cli("reference", "ggx-plastic", "-o", "r.npz", cwd=work).returncode == 0
    _replaced_twice(
        work, "fig.png", "render", "r.npz", "-o", "fig.png", "--size", "8", "--spp", "1"
    )


def test_prior_train_replaces(work):
    """``prior train`` (and ``fit``, whose run is too slow for this file: the same
    ``output_lock`` announces the replacement just before the write)."""
    for m in ("ggx-plastic", "ggx-aniso-metal"):
        assert call_cli("reference", m, "-o", f"t-{m}.npz", cwd=work).returncode == 0
    train = ["prior", "train", "t-ggx-plastic.npz", "t-ggx-aniso-metal.npz", "-o", "pt.npz"]
    _replaced_twice(work, "pt.npz", *train, "--components", "1", "--lam", "0.1", "-q")


def _tables(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.glob("*.npz"))}


def test_folder_run_resumes_same_settings_refuses_others(work):
    d = work / "measurements"
    d.mkdir()
    for k in range(2):
        (d / f"m{k}.csv").write_bytes((work / "meas.csv").read_bytes())
    run = ["reconstruct", "measurements", "-o", "out", "-q", "--model", "iso"]
    assert call_cli(*run, "--format", "npz", cwd=work).returncode == 0
    before, record = _tables(work / "out"), (work / "out.model.json").read_bytes()
    again = call_cli(*run, "--resume", cwd=work)  # the README's pair: same settings, resumed
    assert again.returncode == 0 and "nothing to do" in again.stdout, again.stderr
    other = ["reconstruct", "measurements", "-o", "out", "-q", "--preset", "paper"]
    for extra in ([], ["--resume"]):
        refused = call_cli(*other, *extra, cwd=work)
        assert refused.returncode == 2, refused.stderr
        assert "other settings (model, preset differ)" in refused.stderr
        assert "--overwrite" in refused.stderr and "Traceback" not in refused.stderr
        assert _tables(work / "out") == before
        assert (work / "out.model.json").read_bytes() == record
    done = call_cli(*other, "--overwrite", cwd=work)
    assert done.returncode == 0, done.stderr
    assert "replacing the tables of out (--overwrite)" in done.stderr
    after = _tables(work / "out")
    assert after.keys() == before.keys() and after != before
    settings = json.loads((work / "out.model.json").read_text())["settings"]
    assert settings["preset"] == "paper" and settings["model"] == "auto"


def test_btf_store_resumes_same_settings_refuses_others(work):
    gen = ["btf", "generate", "-o", "g", "--size", "4", "--seed", "1", "-q"]
    r = call_cli(*gen, cwd=work)
    assert r.returncode == 0, r.stderr
    refused = call_cli("btf", "generate", "-o", "g", "--size", "4", "--seed", "2", "-q", cwd=work)
    assert refused.returncode == 2 and "pass --overwrite to replace it" in refused.stderr
    rec = ["btf", "reconstruct", "g", "-o", "g/rec", "-q"]
    for _ in range(2):
        r = call_cli(*rec, cwd=work)
        assert r.returncode == 0, r.stderr
    assert "0 chunks computed" in r.stdout  # resumed: nothing left to do
    chunks = {p.name: p.read_bytes() for p in (work / "g" / "rec").rglob("*") if p.is_file()}
    refused = call_cli(*rec, "--preset", "paper", cwd=work)
    assert refused.returncode == 2 and "pass --overwrite to replace it" in refused.stderr
    kept = {p.name: p.read_bytes() for p in (work / "g" / "rec").rglob("*") if p.is_file()}
    assert kept == chunks
    r = call_cli(*rec, "--preset", "paper", "--overwrite", cwd=work)
    assert r.returncode == 0 and "0 chunks computed" not in r.stdout, r.stderr
    _replaced_twice(work, "map.png", "btf", "evaluate", "g/rec", "g/reference", "--png", "map.png")
