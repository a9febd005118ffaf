"""Real captures: dense, jittered, noisy, other geometry, gaps, through the command line.

Run: ``python -m benchmarks.captures [--quick] [--sets merl,aniso] [--kinds K1,K2]``. Writes
``benchmarks/results/captures.json``, the README table ``captures.md`` and the charts
``captures_density.png`` (error against samples per slice) and ``captures_noise.png`` (error
against value noise and angle jitter); ``--quick`` writes ``captures_quick.*`` instead.

For each material set (``merl``: the MERL test split captured with the iso102 budget; ``aniso``:
the package's analytic anisotropic materials, aniso204) and each capture kind
(:data:`benchmarks._captures_kinds.KINDS`: the protocol capture, dense slices, positional
jitter, value noise, other α, elevations off the UBO rings, two extra pairs, a gap), every
material is captured by :func:`abrdf_jax.simulate_capture` and written as a CSV into one folder;
the folder is reconstructed by ONE call of the command line as a user runs it
(``python -m abrdf_jax.cli reconstruct DIR -o OUT -q``, default ``--model auto``); its exit code,
wall time and warnings are recorded, the output tables read back and checked (shape, finite),
and ΔE76 and LogErr computed against the dense truth (``materials.dense_table``). Beside the
package: the scipy peer with the paper's configuration (``Config(budget)`` and
``Params.default(config, alpha_deg=the capture's α)``; its slice split uses a fixed 0.5°
tolerance at PROTOCOL.md's pairs, so it is "n/a" with the reason where it raises or returns a
non-finite table) and mean fill (every value the mean of the samples). Issue 12's targets are
checked and printed as PASS/FAIL (:func:`benchmarks._captures_kinds.check_targets`).
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import abrdf_jax as aj
from abrdf_jax import io, materials, metrics

from ._captures_kinds import KINDS, QUICK_KINDS, SETS, check_targets, protocol_pair_cells
from ._captures_report import charts, markdown, pass_fail_lines
from ._common import RESULTS, load_average, machine, write_json

REPO = Path(__file__).resolve().parents[1]
#: Seed of material ``i``'s capture: ``SEED + i`` (the same in every kind).
SEED = 12
CLI = ("python", "-m", "abrdf_jax.cli", "reconstruct")


#: Where the error lies: mean ΔE76 over the cells at the protocol's pairs and over the rest.
SPLIT = ("de76_protocol_pairs", "de76_elsewhere")
_CELLS = protocol_pair_cells()


def summary(per: dict[str, dict]) -> dict:
    """Mean and median ΔE76 and LogErr over materials, the means of :data:`SPLIT`, and the
    per-material figures."""
    out = {}
    for key in ("de76", "logerr"):
        v = np.array([m[key] for m in per.values()], float)
        out[key], out[f"{key}_median"] = float(np.mean(v)), float(np.median(v))
    for key in SPLIT:
        out[key] = float(np.mean([m[key] for m in per.values()]))
    return out | {"per_material": per}


def errors(rec, ref) -> dict:
    """ΔE76 and LogErr of one table, and ΔE76 split by :func:`protocol_pair_cells` (the mean
    of the per-pair map :func:`abrdf_jax.metrics.delta_e76_pairs` is ΔE76 itself)."""
    rec, ref = np.asarray(rec, np.float32), np.asarray(ref, np.float32)
    m = metrics.evaluate(rec, ref)
    de = np.asarray(metrics.delta_e76_pairs(rec, ref))
    return {
        "de76": float(m["de76"]),
        "logerr": float(m["logerr"]),
        SPLIT[0]: float(de[_CELLS].mean()),
        SPLIT[1]: float(de[~_CELLS].mean()),
    }


def valid(table) -> str | None:
    """Why ``table`` is not a valid ABRDF table, or ``None``."""
    t = np.asarray(table)
    if t.shape != (81, 81, 3):
        return f"shape {t.shape}, expected (81, 81, 3)"
    if not np.all(np.isfinite(t)):
        return f"{int(np.sum(~np.isfinite(t)))} non-finite values"
    return None


# --------------------------------------------------------------------------------------------
# One capture kind of one set
# --------------------------------------------------------------------------------------------


def run_cli(folder: Path, out: Path, names: list[str], extra: tuple[str, ...] = ()) -> dict:
    """Reconstruct ``folder`` by one call of the command line (``extra``: more arguments, e.g.
    a fixed ``--model``); exit code, time, warnings."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, *CLI[1:], str(folder), "-o", str(out), "-q", *extra]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=folder.parent)
    seconds = time.perf_counter() - t0
    lines = proc.stderr.replace(f"{folder.parent.parent}{os.sep}", "").splitlines()
    warns = [x for x in lines if "warning:" in x]
    errs = [x for x in lines if "error:" in x]
    shown = f"{folder.parent.name}/{folder.name}"
    res = {
        "command": shlex.join([*CLI, shown, "-o", shown + ".out", "-q", *extra]),
        "exit_code": proc.returncode,
        "seconds": seconds,
        "warnings": len(warns),
        "warning_lines": warns[:20],
        "error_lines": errs[:5],
    }
    tables, invalid = {}, {}
    for n in names if proc.returncode == 0 else []:
        path = out / f"{_file(n)}.npz"
        try:
            t = io.read_table(path)
        except Exception as e:  # noqa: BLE001 - recorded: a missing or unreadable output
            invalid[n] = f"{type(e).__name__}: {e}"
            continue
        why = valid(t)
        if why is None:
            tables[n] = t
        else:
            invalid[n] = why
    res["invalid"] = invalid
    res["ok"] = proc.returncode == 0 and not invalid and len(tables) == len(names)
    return res | {"tables": tables}


def _shown(path) -> str:
    """``path`` relative to the repository where it lies inside it."""
    p = Path(path).resolve()
    return str(p.relative_to(REPO)) if p.is_relative_to(REPO) else str(p)


def _file(name: str) -> str:
    return name.removeprefix(materials.NBRDF_PREFIX)


def scipy_tables(samples: dict, budget: str, alpha_deg: float) -> tuple[dict, dict]:
    """The scipy peer's tables (paper config) where it runs, and why not elsewhere."""
    from .scipy_peer import reconstruct_samples

    config = aj.Config(budget=budget)
    params = aj.Params.default(config, alpha_deg=alpha_deg)
    tables, why = {}, {}
    for n, s in samples.items():
        try:
            with np.errstate(all="ignore"):
                t = reconstruct_samples(s, config, params)
        except Exception as e:  # noqa: BLE001 - recorded as "n/a" with the reason
            why[n] = f"{type(e).__name__}: {e}"
            continue
        bad = valid(t)
        if bad is None:
            tables[n] = t
        else:
            why[n] = bad
    return tables, why


def method_result(tables: dict, refs: dict, why: dict | str | None = None) -> dict:
    """Figures of one method over the set, or ``{"n/a": reason}`` unless every material ran."""
    if isinstance(why, str):
        return {"n/a": why}
    if why:
        first = next(iter(why.items()))
        return {"n/a": f"{len(why)} of {len(refs)} materials: {first[0]}: {first[1]}"}
    return summary({n: errors(tables[n], refs[n]) for n in refs})


def run_kind(set_name: str, kind_name: str, models: dict, refs: dict, work: Path, log) -> dict:
    """Capture every material of a set, reconstruct the folder, compute the figures."""
    mset, kind = SETS[set_name], KINDS[kind_name]
    folder = work / set_name / kind_name
    folder.mkdir(parents=True)
    samples = {}
    for i, (n, model) in enumerate(models.items()):
        kw = {"budget": mset.budget, "seed": SEED + i, **kind.capture}
        samples[n] = aj.simulate_capture(model, **kw)
        io.write_samples_csv(folder / f"{_file(n)}.csv", samples[n])
    cli = run_cli(folder, work / set_name / f"{kind_name}.out", list(models))
    tables = cli.pop("tables")
    if cli["exit_code"] != 0:
        package = {"n/a": f"exit {cli['exit_code']}: " + " / ".join(cli["error_lines"])[:500]}
    else:
        package = method_result(tables, refs, cli["invalid"])
    peer, why = scipy_tables(samples, mset.budget, kind.alpha_deg)
    fill = {
        n: np.broadcast_to(np.mean(np.asarray(s.rgb), 0), (81, 81, 3)) for n, s in samples.items()
    }
    res = {
        "what": kind.what,
        "capture": {k: v for k, v in kind.capture.items()},
        "n_samples": {n: len(s) for n, s in samples.items()},
        "cli": cli,
        "package": package,
        "scipy": method_result(peer, refs, why),
        "mean_fill": method_result(fill, refs),
    }
    de = package.get("de76")
    log(
        f"  {set_name:5s} {kind_name:12s} exit {cli['exit_code']} {cli['seconds']:6.1f} s "
        f"{cli['warnings']:3d} warnings  ΔE76 "
        + (f"{de:6.2f}" if de is not None else "   n/a")
        + "  scipy "
        + ("   n/a" if "n/a" in res["scipy"] else f"{res['scipy']['de76']:6.2f}")
        + f"  mean fill {res['mean_fill']['de76']:6.2f}"
    )
    return res


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------


def _choices(text: str | None, allowed, what: str, default) -> list[str]:
    if text is None:
        return list(default)
    got = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in got if t not in allowed]
    if bad or not got:
        raise SystemExit(f"unknown {what} {bad or text!r}; choose from {', '.join(allowed)}")
    return [t for t in allowed if t in got]  # in the registry's order


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 MERL + 2 aniso materials, 8 kinds")
    ap.add_argument("--sets", help=f"comma list of {', '.join(SETS)} (default both)")
    ap.add_argument("--kinds", help=f"comma list of {', '.join(KINDS)}")
    ap.add_argument("--out", type=Path, default=RESULTS, help="results folder")
    ap.add_argument("--no-plot", action="store_true", help="skip the charts")
    return ap.parse_args(argv)


def main(argv=None, log=None) -> dict:
    args = parse_args(argv)
    log = log or (lambda s: print(s, flush=True))
    sets = _choices(args.sets, list(SETS), "set", SETS)
    kinds = _choices(args.kinds, list(KINDS), "kind", QUICK_KINDS if args.quick else KINDS)
    suffix = "_quick" if args.quick else ""
    argv_text = shlex.join(["python", "-m", "benchmarks.captures", *(argv or sys.argv[1:])])
    payload = {
        "mode": "quick" if args.quick else "full",
        "machine": machine(),
        "load_average_before": load_average(),
        "commands": {"benchmark": argv_text},
        "seed": SEED,
        "sets": {},
    }
    t0 = time.perf_counter()
    results = {}
    with tempfile.TemporaryDirectory(prefix="captures-") as tmp:
        for set_name in sets:
            mset = SETS[set_name]
            names = mset.names(args.quick)
            log(f"{set_name}: {len(names)} materials ({mset.budget}), {len(kinds)} kinds")
            models = {_file(n): materials.get_material(n) for n in names}  # by file name
            refs = {n: materials.dense_table(m) for n, m in models.items()}
            results[set_name] = {
                k: run_kind(set_name, k, models, refs, Path(tmp), log) for k in kinds
            }
            payload["sets"][set_name] = {
                "budget": mset.budget,
                "what": mset.what,
                "materials": [_file(n) for n in names],
                "kinds": results[set_name],
            }
    payload["targets"] = check_targets(results)
    payload["seconds"] = time.perf_counter() - t0
    payload["load_average_after"] = load_average()
    payload["commands"]["reconstruct"] = "python -m abrdf_jax.cli reconstruct DIR -o OUT -q"
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.no_plot:
        payload["charts"] = [_shown(p) for p in charts(payload, args.out, suffix)]
    md = markdown(payload)
    (args.out / f"captures{suffix}.md").write_text(md)
    write_json(args.out / f"captures{suffix}.json", payload)
    log(md)
    for line in pass_fail_lines(payload):
        log(line)
    log(f"{payload['seconds']:.0f} s; wrote {_shown(args.out / f'captures{suffix}.json')}")
    return payload


if __name__ == "__main__":
    main()
