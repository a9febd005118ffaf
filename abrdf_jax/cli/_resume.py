"""``reconstruct DIR --resume``: which outputs a run keeps, and where the kept tables sat in the
uninterrupted run's batches (so that the resumed tables get the same bits)."""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError


def resumable(files: list[Path], targets: list[Path], out: Path):
    """``--resume``: the inputs whose table is already complete and valid in ``out`` and named
    in its model record are kept (their record entries with them); the others are redone."""
    import json

    from .. import io

    record = out.parent / (out.name + ".model.json")
    try:
        entries = {e["input"]: e for e in json.loads(record.read_text())["inputs"]}
    except (OSError, ValueError, KeyError, TypeError):
        entries = {}  # no record (or a torn one): nothing is known to be finished
    todo, kept = [], []
    for f, t in zip(files, targets):
        entry = entries.get(str(f))
        if entry is not None and t.exists():
            try:
                io.read_table(t)  # complete and finite, or redone
                kept.append({"record": entry})
                continue
            except InputError:
                pass
        todo.append((f, t))
    return [f for f, _ in todo], [t for _, t in todo], kept


def settings_key(record: dict) -> str:
    """What, besides the slice layout, one operator depends on: a record entry's configuration,
    parameters and slice offset."""
    import json

    return json.dumps([record.get("config"), record.get("params")], sort_keys=True)


def kept_batches(kept: list[dict], place: dict[str, int]) -> dict[str, list]:
    """``{settings: [Done, ...]}`` of the tables a ``--resume`` run keeps (their record's
    ``batch`` entry and place in the job): :func:`abrdf_jax._engine.reconstruct_many` gives each
    table it makes the path, batch row and padding it gets in one uninterrupted run, hence the
    same bits. (Entries of records written before ``batch`` count nothing.)"""
    from .._engine import Done

    out: dict[str, list] = {}
    for choice in kept:
        rec = choice["record"]
        b = rec.get("batch")
        if isinstance(b, dict) and rec.get("input") in place:
            small = b.get("small") if isinstance(b.get("small"), bool) else None
            done = Done(
                b.get("layout"), b.get("group"), place[rec["input"]], int(b.get("width", 0)), small
            )
            out.setdefault(settings_key(rec), []).append(done)
    return out
