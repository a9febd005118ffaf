"""The model record of ``abrdf-jax reconstruct`` (``OUT.model.json``): what model made each
table, and why. Used through :mod:`abrdf_jax.cli._common`."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

MODEL_FORMAT = "abrdf_jax.model/1"


def model_choice(where: Path, name, config, params, how: str, reason: str, extra=None) -> dict:
    """One input's model: ``{"name", "config", "params", "record"}`` (``record``: its JSON entry)."""
    from ..io._paramfile import params_to_dict

    p = params_to_dict(config, params)
    rec = {"input": str(where), "model": name, "how": how, "config": p["config"]}
    rec |= {"params": p["params"], "reason": reason, **(extra or {})}
    return {"name": name, "config": config, "params": params, "record": rec}


def save_model_record(out: Path, choices: list[dict], folder_mode: bool, settings=None) -> Path:
    """Write the model record(s) atomically to ``OUT.model.json``, beside the output file or
    folder. A folder's record has one entry per line, each serialised once (``choice["json"]``):
    a run rewrites it after its batches; it also holds the run's ``settings`` (the overwrite
    policy compares a rerun's with them)."""
    from ..io import atomic_write

    out = Path(out)
    path = out.parent / ((out.name if folder_mode else out.stem) + ".model.json")
    if not folder_mode:
        doc = {"format": MODEL_FORMAT, **choices[0]["record"]}
        with atomic_write(path, "w") as fh:
            fh.write(json.dumps(_clean(doc), indent=2, allow_nan=False) + "\n")
        return path
    head = f'  "format": {json.dumps(MODEL_FORMAT)},\n'
    if settings is not None:
        head += f'  "settings": {json.dumps(_clean(settings), sort_keys=True)},\n'
    with atomic_write(path, "w") as fh:  # entry by entry: no second copy of a large record
        fh.write(f'{{\n{head}  "inputs": [\n')
        for k, c in enumerate(choices):
            fh.write(("    " if k == 0 else ",\n    ") + _entry_json(c))
        fh.write("\n  ]\n}\n")
    return path


def _entry_json(choice: dict) -> str:
    """One record entry as compact JSON, made once per choice (non-finite numbers as null)."""
    if "json" not in choice:
        rec, compact = choice["record"], dict(separators=(", ", ": "), allow_nan=False)
        try:  # numpy scalars as numbers; a NaN raises and takes the slow, cleaning path
            text = json.dumps(
                rec, default=lambda o: o.item() if hasattr(o, "item") else str(o), **compact
            )
        except ValueError:
            text = json.dumps(_clean(rec), **compact)
        choice["json"] = text
    return choice["json"]


def _clean(x):
    """JSON-safe copy: non-finite floats as ``None``, numpy scalars as Python numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (bool, int, str)) or x is None:
        return x
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None


def describe(choice: dict) -> list[str]:
    """Lines printed for one measurement's model."""
    rec = choice["record"]
    name = rec["model"] or "from parameter file"
    lines = [f"  model: {name} ({rec['how']}): {rec['reason']}"]
    lines += describe_prior(rec)
    if "measurement" in rec:
        m = rec["measurement"]
        per = ", ".join(
            f"{tuple(p)} {c['axial']}+{c['diagonal']}"
            for p, c in zip(m["pairs"], m["samples_per_slice"])
        )
        left = m["n_samples"] - m["n_used"]
        lines.append(
            f"  used: {m['n_used']} of {m['n_samples']} samples, axial+diagonal per pair {per}"
            + (f"; {left} left out" if left else "")
        )
        alpha = f"alpha {m['alpha_deg']:.3f} +- {m['alpha_se_deg']:.3f} deg"
        # on sparse slices the neighbour residuals hold the slices' own curvature: an upper bound
        dense = min(c["diagonal_knots"] for c in m["samples_per_slice"]) >= 48
        noise = "n/a" if m.get("noise_log") is None else f"{100 * m['noise_log']:.2g} %"
        noise = noise if dense or noise == "n/a" else f"<= {noise} (sparse slices: an upper bound)"
        lines.append(
            f"  capture: {alpha}, slice tolerance {m['tolerance_deg']:.2g} deg, noise {noise}"
            + (f", {len(m['gaps'])} gap(s)" if m["gaps"] else "")
        )
    if rec.get("smoothing"):
        sm = rec["smoothing"]
        noise = "" if sm["noise_log"] is None else f" from noise {sm['noise_log']:.3g} (log)"
        beta = ", ".join(f"{b:.2f}" for b in sm["beta"])
        lines.append(f"  slice smoothing: weight per slice {beta}{noise}")
    for c in rec.get("candidates") or []:
        err = "n/a" if c["held_out_log_rms"] is None else f"{c['held_out_log_rms']:.4f}"
        mark = "*" if c["name"] == rec["model"] else " "
        lines.append(f"   {mark} {c['name']:<15} rank {c['rank']}  held-out log RMS {err}")
    return lines


def summary(models) -> str:
    """``"iso x2, aniso-crossing x1"``: how often each model (a record's ``model``) was used."""
    counts = Counter(m or "parameter file" for m in models)
    return ", ".join(f"{n} x{k}" for n, k in counts.items())


def compact(choice: dict) -> dict:
    """What a folder's record keeps of a finished choice: its entry's JSON only (about 2 KiB;
    the choice itself holds configuration, parameters and report, several times that)."""
    return {"json": _entry_json(choice)}


def describe_prior(rec: dict) -> list[str]:
    """The printed line of a record's prior (none for other models)."""
    p = rec.get("prior")
    if not p:
        return []
    where = p["file"] or "default prior, built in memory (cache off)"
    return [
        f"  prior: {where} (sha256 {p['sha256'][:12]}..., K {p['n_components']}, lambda "
        f"{p['lam']:g}, {p['n_materials']} training tables): {p['provenance']}"
    ]
