"""``abrdf-jax reconstruct --model``: which model reconstructs each measurement, and why.

``--model auto`` (the default) runs :func:`abrdf_jax.select.select_model` on every input (the
isotropy test on the axial slices, then held-out errors with the tolerance rule), prints the
choice, the candidates' held-out errors and the reason, and saves them as JSON beside the output
(``OUT.model.json`` for an output file ``OUT.npz``/``OUT.exr``; for an output folder ``OUT/``,
one ``OUT.model.json`` beside the folder holding every input's entry). ``--model NAME`` fixes a
candidate (``iso``, ``aniso``, ``aniso-crossing``, ... see ``abrdf_jax.select.CANDIDATES``);
``--params PARAMS.json`` fixes the model from a fitted parameter file; ``--preset paper`` fixes
the paper's method. ``--isotropic``/``--anisotropic`` force the budget: ``auto`` then chooses
among that budget's candidates only.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from .._errors import InputError

FORMAT = "abrdf_jax.model/1"


def add_arguments(parser) -> None:
    """The ``--model``, ``--tol`` and ``--noise`` options of ``abrdf-jax reconstruct``."""
    from ..select._select import CANDIDATES, TOL

    parser.add_argument("--model", metavar="MODEL", default=None,
                        help="auto (default: isotropy test, then the simplest candidate within --tol of the best "
                             "held-out error) or a fixed model: " + ", ".join(CANDIDATES))
    parser.add_argument("--tol", type=float, default=TOL, metavar="FRAC",
                        help=f"tolerance of the automatic choice, relative (default {TOL:g})")
    parser.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                        help="relative noise of one sample for the isotropy test (default: estimated from the data)")


def check_arguments(args) -> None:
    """Fail before any work on contradictory model options."""
    from ..select._select import candidate

    if args.model is not None and args.model != "auto":
        candidate(args.model)  # unknown names fail here, listing the valid ones
        if args.params is not None:
            raise InputError(f"--model {args.model} and --params {args.params} both fix the model; give one")
        budget = candidate(args.model).settings["budget"]
        if args.anisotropic and budget != "aniso204":
            raise InputError(f"--model {args.model} is isotropic (iso102) but --anisotropic was given")
        if args.isotropic and budget != "iso102":
            raise InputError(f"--model {args.model} needs the axial slices (aniso204) but --isotropic was given")
    if not (math.isfinite(args.tol) and args.tol >= 0):
        raise InputError(f"--tol must be a fraction >= 0, got {args.tol}")
    if args.noise is not None and not (math.isfinite(args.noise) and args.noise >= 0):
        raise InputError(f"--noise must be a relative level >= 0, got {args.noise}")


def model_json_path(out: Path, folder_mode: bool) -> Path:
    """Where the model record goes: ``OUT.model.json`` beside the output file or folder."""
    out = Path(out)
    if folder_mode:
        return out.parent / (out.name.rstrip("/") + ".model.json")
    return out.with_name(out.stem + ".model.json")


def choose(aj, samples, budget: str, alpha: float, args, where: Path, forced: str | None) -> dict:
    """The model for one measurement: ``{"name", "config", "params", "record"}``.

    ``budget``/``alpha`` come from :func:`abrdf_jax.cli._plan`; ``forced`` is the budget of
    ``--isotropic``/``--anisotropic`` (``None`` when not given).
    """
    from . import _params_for
    from ..io._paramfile import params_to_dict
    from ..select._select import CANDIDATES, candidate, select_model

    def record(name, config, params, how, reason, extra=None):
        p = params_to_dict(config, params)
        rec = {"input": str(where), "model": name, "how": how, "config": p["config"], "params": p["params"],
               "reason": reason}
        rec.update(extra or {})
        return {"name": name, "config": config, "params": params, "record": rec}

    if args.params is not None:
        config, params = _params_for(aj, budget, alpha, args.preset, args.params)
        return record(None, config, params, "params", f"parameters and model fixed by {args.params}")
    model = args.model
    if model is None and args.preset == "paper":
        model = "paper-aniso" if budget == "aniso204" else "paper"
    if model is not None and model != "auto":
        c = candidate(model)
        if c.settings["budget"] == "aniso204" and budget != "aniso204":
            raise InputError(f"{where}: --model {model} needs axial slices (aniso204), but the measurement has none")
        config = c.config()
        params = aj.Params.default(config, alpha_deg=alpha)
        how = "preset" if args.model is None else "fixed"
        why = f"--preset paper: {c.description}" if how == "preset" else f"--model {model}: {c.description}"
        return record(model, config, params, how, why, {"rank": c.rank})
    try:
        sel = select_model(samples, budget=forced, tol=args.tol, noise=args.noise, alpha_deg=alpha)
    except InputError as e:
        raise InputError(f"{where}: {e}") from e
    d = sel.to_dict()
    extra = {"rank": CANDIDATES[sel.name].rank, "tol": sel.tol, "folds": sel.k, "candidates": d["candidates"],
             "isotropy": d["isotropy"], "seconds": sel.seconds}
    return record(sel.name, sel.config, sel.params, "auto", sel.reason, extra)


def describe(choice: dict) -> list[str]:
    """Lines printed for one measurement's model."""
    rec = choice["record"]
    name = rec["model"] or "from parameter file"
    lines = [f"  model: {name} ({rec['how']}): {rec['reason']}"]
    for c in rec.get("candidates") or []:
        err = "n/a" if c["held_out_log_rms"] is None else f"{c['held_out_log_rms']:.4f}"
        mark = "*" if c["name"] == rec["model"] else " "
        lines.append(f"   {mark} {c['name']:<15} rank {c['rank']}  held-out log RMS {err}")
    return lines


def save(path: Path, choices: list[dict], folder_mode: bool) -> Path:
    """Write the model record(s) atomically."""
    from ..io._atomic import atomic_write

    doc = {"format": FORMAT}
    if folder_mode:
        doc["inputs"] = [c["record"] for c in choices]
    else:
        doc.update(choices[0]["record"])
    text = json.dumps(_clean(doc), indent=2, allow_nan=False)
    with atomic_write(path, "w") as fh:
        fh.write(text + "\n")
    return path


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


def choose_all(aj, samples, plans, files, args, forced, quiet: bool = False) -> list[dict]:
    """:func:`choose` for every input, with a progress bar when there are several."""
    from tqdm import tqdm

    out = []
    with tqdm(total=len(files), desc="select model", unit="file", file=sys.stderr,
              disable=quiet or len(files) < 2, dynamic_ncols=True) as bar:
        for s, (budget, alpha), f in zip(samples, plans, files):
            out.append(choose(aj, s, budget, alpha, args, f, forced))
            bar.update(1)
    return out


def summary(choices: list[dict]) -> str:
    """``"iso x2, aniso-crossing x1"``: how often each model was used."""
    counts: dict = {}
    for c in choices:
        name = c["record"]["model"] or "parameter file"
        counts[name] = counts.get(name, 0) + 1
    return ", ".join(f"{n} x{k}" for n, k in counts.items())


