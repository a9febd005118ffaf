"""The commands the SIGKILL harness (:mod:`benchmarks._kill`) kills, with their inputs: a
folder of simulated captures for ``abrdf-jax reconstruct DIR``, a procedural BTF for ``abrdf-jax
btf reconstruct``, one capture for ``abrdf-jax fit self``. For each: what a valid output is
(absent, or complete and valid), what of the result must be bit-identical, and how many pieces
of it are on disk. Shared by ``tests/test_kill.py`` and ``python -m benchmarks.faults``."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

import abrdf_jax as aj
from abrdf_jax import btf, io, materials, tuning
from abrdf_jax.io import is_temp

from ._kill import Command

#: The materials of the simulated captures (analytic: no shared data needed).
MATERIALS = ("ggx-plastic", "lambert-clay", "ward-brushed-steel", "ashikhmin-satin")
#: The record format of ``reconstruct`` (``OUT.model.json``).
MODEL_FORMAT = "abrdf_jax.model/1"
#: What a result may change between two runs of the same command: durations and dates.
VOLATILE = ("seconds", "compile_seconds", "date")


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------


def write_captures(folder: Path, n: int, seed: int = 0) -> Path:
    """``n`` iso102 captures (1 % noise) of :data:`MATERIALS` in turn, at α 15 and 20 degrees
    in turn (two slice layouts, so a folder run makes two groups), as ``folder/cNNN.csv``."""
    folder.mkdir(parents=True, exist_ok=True)
    models = [materials.get_material(m) for m in MATERIALS]
    for k in range(n):
        s = aj.simulate_capture(
            models[k % len(models)],
            budget="iso102",
            alpha_deg=15.0 + 5.0 * (k % 2),
            noise=0.01,
            seed=seed + k,
        )
        io.write_samples_csv(folder / f"c{k:03d}.csv", s)
    return folder


def write_btf(folder: Path, size: int, seed: int = 1) -> Path:
    """A procedural ``size`` x ``size`` BTF (``abrdf-jax btf generate``) in ``folder``."""
    btf.generate_btf(folder, size, seed=seed, reference=False, maps=False)
    return folder


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _without(x, keys=VOLATILE):
    """``x`` with every dict entry named in ``keys`` removed, at any depth."""
    if isinstance(x, dict):
        return {k: _without(v, keys) for k, v in x.items() if k not in keys}
    if isinstance(x, list):
        return [_without(v, keys) for v in x]
    return x


def _canonical(x) -> bytes:
    return json.dumps(_without(x), sort_keys=True).encode()


def _array_bytes(a: np.ndarray) -> bytes:
    return f"{a.dtype.str}{a.shape}".encode() + np.ascontiguousarray(a).tobytes()


def _said(pattern: str, text: str) -> int:
    """The number the last match of ``pattern`` (any of its groups) found in ``text``, or 0."""
    found = [g for m in re.finditer(pattern, text) for g in m.groups() if g]
    return int(found[-1]) if found else 0


def _json(path: Path, problems: list[str]):
    """The JSON document in ``path``, or ``None`` with the reason appended to ``problems``."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        problems.append(f"{path.name}: not a readable JSON document ({e})")
        return None


# --------------------------------------------------------------------------------------------
# reconstruct DIR -o OUT/
# --------------------------------------------------------------------------------------------


def _tables(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix == ".npz" and not is_temp(p.name))


def _check_folder(out: Path) -> list[str]:
    """Every table in ``out/R`` reads back (81 x 81 x 3, finite); the record, if there, is valid
    and every table it names is there."""
    folder, record, problems = out / "R", out / "R.model.json", []
    valid = set()
    for t in _tables(folder):
        try:
            io.read_table(t)
            valid.add(t.stem)
        except aj.InputError as e:
            problems.append(f"partial or invalid table: {e}")
    if record.exists():
        doc = _json(record, problems)
        if doc is not None:
            if doc.get("format") != MODEL_FORMAT or not isinstance(doc.get("inputs"), list):
                problems.append(f"{record.name}: not a model record ({str(doc)[:200]})")
            else:
                named = [Path(e["input"]).stem for e in doc["inputs"]]
                missing = sorted(set(named) - valid)
                if missing:
                    problems.append(f"{record.name} names tables that are not there: {missing}")
                if len(named) != len(set(named)):
                    problems.append(f"{record.name} names a table twice")
    return problems


def _digest_folder(out: Path) -> dict[str, bytes]:
    d = {f"table {t.name}": _array_bytes(io.read_table(t)) for t in _tables(out / "R")}
    doc = json.loads((out / "R.model.json").read_text())
    d["record settings"] = _canonical(doc.get("settings"))
    for e in doc["inputs"]:
        d[f"record {Path(e['input']).name}"] = _canonical(e)
    return d


def reconstruct_dir(captures: Path) -> Command:
    """``abrdf-jax reconstruct CAPTURES -o OUT/R -q``; rerun with ``--resume``."""
    return Command(
        name="reconstruct DIR",
        argv=lambda out: ["reconstruct", captures, "-o", out / "R", "-q"],
        outputs=lambda out: [out / "R", out / "R.model.json"],
        check=_check_folder,
        digest=_digest_folder,
        pieces=lambda out: len(_tables(out / "R")),
        rerun=("--resume",),
        kept=lambda said: _said(r"(\d+) kept \(--resume\)|all (\d+) tables are complete", said),
    )


# --------------------------------------------------------------------------------------------
# btf reconstruct D -o OUT/R
# --------------------------------------------------------------------------------------------


def _markers(store: Path) -> list[Path]:
    chunks = store / "chunks"
    if not chunks.is_dir():
        return []
    return sorted(p for p in chunks.iterdir() if p.suffix == ".json" and not is_temp(p.name))


def _check_store(out: Path) -> list[str]:
    """The store, if there, opens; every chunk with a marker (what the store counts as done)
    verifies (size and crc32); a store without its manifest holds no chunk."""
    store = out / "R"
    if not store.exists():
        return []
    if not (store / "manifest.json").exists():
        if _markers(store):
            return ["chunks written before the store's manifest"]
        return []
    try:
        s = btf.open_store(store)
    except aj.InputError as e:
        return [f"the store does not open: {e}"]
    problems = []
    for m in _markers(store):
        k = int(m.stem.lstrip("c"))
        status = s.chunk_status(k, verify=True)
        if status != "done":
            problems.append(f"chunk {k} has its marker but is not valid: {status}")
    return problems


def _digest_store(out: Path) -> dict[str, bytes]:
    s = btf.open_store(out / "R")
    manifest = json.loads((out / "R" / "manifest.json").read_text())
    return {"values": _array_bytes(s.read()), "manifest": _canonical(manifest)}


def btf_reconstruct(source: Path, chunk: int) -> Command:
    """``abrdf-jax btf reconstruct SOURCE -o OUT/R --chunk CHUNK -q``; rerun as it is."""
    return Command(
        name="btf reconstruct",
        argv=lambda out: ["btf", "reconstruct", source, "-o", out / "R", "--chunk", chunk, "-q"],
        outputs=lambda out: [out / "R"],
        check=_check_store,
        digest=_digest_store,
        pieces=lambda out: len(_markers(out / "R")),
        kept=lambda said: _said(r"chunks computed, (\d+) already done", said),
    )


# --------------------------------------------------------------------------------------------
# fit self MEAS.csv -o OUT/P.json
# --------------------------------------------------------------------------------------------


def _check_params(out: Path) -> list[str]:
    path = out / "P.json"
    if not path.exists():
        return []
    try:
        _, params, fit = tuning.load_params(path)
    except aj.InputError as e:
        return [f"partial or invalid parameter file: {e}"]
    values = [float(params.alpha_deg), float(params.reg), *map(float, np.asarray(params.widths))]
    problems = [] if all(map(math.isfinite, values)) else [f"non-finite parameters {values}"]
    if fit.get("mode") != "self" or "status" not in fit:
        problems.append(f"P.json: its 'fit' section lacks the mode or status: {fit}")
    return problems


def fit_self(capture: Path, steps: int) -> Command:
    """``abrdf-jax fit self CAPTURE -o OUT/P.json --steps STEPS --widths fixed -q`` (λ alone:
    the smallest fit); rerun as it is."""
    return Command(
        name="fit self",
        argv=lambda out: [
            *("fit", "self", capture, "-o", out / "P.json"),
            *("--steps", steps, "--widths", "fixed", "-q"),
        ],
        outputs=lambda out: [out / "P.json"],
        check=_check_params,
        digest=lambda out: {"P.json": _canonical(json.loads((out / "P.json").read_text()))},
        pieces=lambda out: int((out / "P.json").exists()),
    )
