"""Processes running at once (issue 16; docs/stability.md, "Faults"): two ``reconstruct`` runs
populating one empty cache folder (operators and JAX's compilation cache) never corrupt it, and
a warm run gives bit-identical tables; two runs writing one output either both finish or one is
refused naming the other's pid, and the output is never a mix of the two (the table always
belongs to the input its model record names)."""

import hashlib
import json

import numpy as np

from abrdf_jax import io
from abrdf_jax._cache import OperatorStore
from abrdf_jax.cli import main
from abrdf_jax.io._atomic import is_temp
from cli_runner import start_cli

MATERIALS = {"a": "ggx-plastic", "b": "lambert-clay"}


def _finish(procs):
    done = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        done.append((p.pid, p.returncode, out, err))
    return done


def _cache_files(folder):
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in folder.rglob("*")
        if p.is_file()
    }


def _every_entry_loads(cache):
    """Every operator entry passes its own checks (key, format, sha256 of the arrays) and every
    compiled function decompresses as JAX reads it; no temporary file is left."""
    from jax._src.compilation_cache import decompress_executable, extract_executable_and_time

    warned = []
    store = OperatorStore(cache, warn=warned.append)
    operators = store.entries()
    assert operators and all(store.load(p.stem) is not None for p in operators) and not warned
    xla = sorted((cache / "xla").glob("*-cache"))
    assert xla
    for f in xla:
        executable, _ = extract_executable_and_time(decompress_executable(f.read_bytes()))
        assert len(executable) > 0, f
    assert not [p for p in cache.rglob("*") if is_temp(p.name)]


def test_two_runs_share_one_cache_and_one_output(tmp_path):
    for name, material in MATERIALS.items():
        out = str(tmp_path / f"{name}.csv")
        assert main(["sample", material, "-o", out, "--budget", "aniso204"]) == 0
    cache = tmp_path / "cache"
    # a: the general pipeline (the paper's setting, filip2012 on linear values: compiled, JAX's
    # compilation cache); b: an operator entry (built in numpy: the operator store)
    model = {"a": ["--preset", "paper"], "b": ["--model", "iso"]}
    flags = {n: [*model[n], "--cache-dir", cache] for n in MATERIALS}
    # 1. two runs at once against one empty cache folder
    cold = _finish(
        [
            start_cli("reconstruct", f"{n}.csv", "-o", f"{n}.npz", *flags[n], cwd=tmp_path)
            for n in MATERIALS
        ]
    )
    for _, rc, _, err in cold:
        assert rc == 0 and "warning" not in err, err
    _every_entry_loads(cache)
    before = _cache_files(cache)
    tables = {n: io.read_table(tmp_path / f"{n}.npz") for n in MATERIALS}
    assert not np.array_equal(tables["a"], tables["b"])
    # 2. two warm runs at once into ONE output: both finish (one after the other) or one is
    # refused naming the other; the table is that of the input its record names, bit for bit
    warm = _finish(
        [
            start_cli("reconstruct", f"{n}.csv", "-o", "same.npz", *flags[n], cwd=tmp_path)
            for n in MATERIALS
        ]
    )
    pids = [pid for pid, *_ in warm]
    for (pid, rc, _, err), other in zip(warm, reversed(pids)):
        if rc != 0:
            assert rc == 2 and f"is being written by process {other} on host" in err, err
    assert any(rc == 0 for _, rc, _, _ in warm), warm
    record = json.loads((tmp_path / "same.model.json").read_text())
    winner = record["input"].removesuffix(".csv")
    np.testing.assert_array_equal(io.read_table(tmp_path / "same.npz"), tables[winner])
    # the warm runs compiled and built nothing new: every entry was read as it was written
    after = _cache_files(cache)
    assert after.keys() == before.keys()
    assert [k for k in after if after[k] != before[k]] == []
    assert not [p for p in tmp_path.iterdir() if is_temp(p.name) or p.suffix == ".lock"]
