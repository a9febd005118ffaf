"""Does the slice ``abrdf-jax suggest`` proposes lower the error more than another one?

Run: ``python -m benchmarks.suggest [--quick]`` → ``results/suggest{_quick}.json``, ``.md`` and
``.png``.

On the MERL test split (54 materials; ``--quick``: 8 of them, every 7th by name), none of which
the default prior or the fused hyper-parameters saw (chosen on MERL *train*): start from the
exact iso102 samples (PROTOCOL.md: the four diagonal slices), rank every candidate slice (the
UBO rings' 36 elevation pairs × axial/diagonal at α = 15°, 26 samples: what ``abrdf-jax suggest
MEAS.csv`` does, :func:`abrdf_jax.prior.suggest_slices`, fused model, default prior), then
measure one more slice (its exact samples from the material's neural model) and reconstruct
with the fused model (:func:`abrdf_jax.prior.reconstruct_fused`, the prior's fixed
hyper-parameters, float64). Slices compared: the suggested one (rank 1); random unmeasured
candidates (``R`` draws per material, seed 0: their mean); two fixed ones, the protocol's next
slice (the axial slice of 30/30, aniso204's first) and a diagonal slice on the middle ring pair
45/45. Mean ΔE76 of each against the dense truth, and per material whether the suggestion beat
the random mean and each fixed slice.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import abrdf_jax as aj  # noqa: E402
from abrdf_jax import prior as P  # noqa: E402

from ._common import RESULTS, load_average, machine, merl_split, metrics_of, write_json  # noqa: E402

SAMPLES = 26
FIXED = {
    "fixed 30/30 axial": ((30.0, 30.0), "axial"),
    "fixed 45/45 diagonal": ((45.0, 45.0), "diagonal"),
}


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


@eqx.filter_jit
def _fused(meas, prior, hyper, reference):
    return P.reconstruct_fused(meas, prior, hyper, reference=reference)


def _measure(model, extra=None):
    """Exact iso102 samples of ``model`` plus, with ``extra = (pair, kind)``, one more slice of
    ``SAMPLES`` samples at the same positions as :func:`abrdf_jax.prior.suggest_slices` scores."""
    counts, pairs = list(aj.protocol_counts("iso102")), list(aj.PROTOCOL_PAIRS)
    if extra is not None:
        pair, kind = extra
        counts += [SAMPLES, 0] if kind == "axial" else [0, SAMPLES]
        pairs.append(pair)
    alpha = jnp.deg2rad(jnp.asarray(aj.PROTOCOL_ALPHA_DEG, jnp.float64))
    return aj.sample_model(model, tuple(counts), alpha, tuple(pairs), dtype=jnp.float64)


def run(names, models, refs, prior, draws: int) -> list[dict]:
    hyper, reference = P.learned_hyper(prior, "fused")
    rng = np.random.default_rng(0)
    rows = []
    for i, name in enumerate(names):
        t = time.perf_counter()
        model = jax.tree_util.tree_map(lambda x, i=i: x[i], models)
        truth = np.asarray(refs[i])[None]

        def de76(meas):
            table = _fused(meas, prior, hyper, reference)
            return float(metrics_of(np.asarray(table)[None], truth)["de76"][0])

        base = _measure(model)
        ranked = P.suggest_slices(base, prior, "fused", samples=SAMPLES)
        by = {(r["pair"], r["kind"]): r["reduction"] for r in ranked}
        best = (ranked[0]["pair"], ranked[0]["kind"])
        picks = rng.choice(len(ranked), draws, replace=False)
        rand = [(ranked[k]["pair"], ranked[k]["kind"]) for k in picks]
        row = {"material": name, "none": de76(base), "suggested_slice": [*best[0], best[1]]}
        row["suggested"] = de76(_measure(model, best))
        row["random_each"] = [de76(_measure(model, c)) for c in rand]
        row["random"] = float(np.mean(row["random_each"]))
        row["random_slices"] = [[*c[0], c[1]] for c in rand]
        for label, c in FIXED.items():
            row[label] = de76(_measure(model, c))
        row["predicted_reduction"] = {
            "suggested": by[best],
            "random": float(np.mean([by[c] for c in rand])),
            **{label: by.get(c) for label, c in FIXED.items()},
        }
        row["seconds"] = time.perf_counter() - t
        _log(
            f"{name:28s} none {row['none']:.2f} suggested {row['suggested']:.2f} "
            f"({best[0][0]:g}/{best[0][1]:g} {best[1]}) random {row['random']:.2f} "
            + " ".join(f"{k[6:]} {row[k]:.2f}" for k in FIXED)
            + f"  ({row['seconds']:.0f} s)"
        )
        rows.append(row)
    return rows


STRATEGIES = ("none", "suggested", "random", *FIXED)


def summary(rows) -> dict:
    out = {s: float(np.mean([r[s] for r in rows])) for s in STRATEGIES}
    out["suggested_beats"] = {
        s: int(sum(r["suggested"] < r[s] for r in rows)) for s in STRATEGIES if s != "suggested"
    }
    out["n"] = len(rows)
    return out


def chart(out: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, s = out["rows"], out["summary"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.bar(range(len(STRATEGIES)), [s[k] for k in STRATEGIES], color="tab:blue")
    a.set_xticks(range(len(STRATEGIES)))
    a.set_xticklabels(["no slice", "suggested", "random", "30/30 axial", "45/45 diag."], fontsize=8)
    a.set_ylabel(f"mean ΔE76 ({s['n']} MERL test materials)")
    a.set_title("one more slice after iso102, fused model", fontsize=9)
    gain = lambda k: [r["none"] - r[k] for r in rows]  # noqa: E731
    for k, m in (("random", "o"), ("fixed 30/30 axial", "s"), ("fixed 45/45 diagonal", "^")):
        b.scatter(gain(k), gain("suggested"), marker=m, s=14, label=k)
    lim = max(1e-3, *np.abs([g for k in STRATEGIES[1:] for g in gain(k)]))
    b.plot([-lim, lim], [-lim, lim], "k--", lw=0.7)
    b.set_xlabel("ΔE76 gained by the other slice")
    b.set_ylabel("ΔE76 gained by the suggested slice")
    b.legend(fontsize=8)
    b.set_title("per material (above the diagonal: suggestion better)", fontsize=9)
    fig.suptitle(f"python -m benchmarks.suggest{' --quick' if out['quick'] else ''}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(out: dict) -> str:
    q = " --quick" if out["quick"] else ""
    s = out["summary"]
    lines = [
        f"# Where to measure next (`python -m benchmarks.suggest{q}`)",
        "",
        f"{out['date']}, load {out['load_average']}, {out['seconds']:.0f} s. MERL test, "
        f"{s['n']} materials, iso102 + one slice of {SAMPLES} samples, fused model, default "
        f"prior; random: {out['draws']} draws per material.",
        "",
        "| slice added | mean ΔE76 | materials where the suggestion is better |",
        "|---|---|---|",
    ]
    for k in STRATEGIES:
        beats = "" if k == "suggested" else f"{s['suggested_beats'][k]} of {s['n']}"
        lines.append(f"| {k} | {s[k]:.3f} | {beats} |")
    lines += ["", "| material | none | suggested (slice) | random | 30/30 axial | 45/45 diagonal |"]
    lines.append("|---|---|---|---|---|---|")
    for r in out["rows"]:
        sl = r["suggested_slice"]
        lines.append(
            f"| {r['material']} | {r['none']:.2f} | {r['suggested']:.2f} ({sl[0]:g}/{sl[1]:g} "
            f"{sl[2]}) | {r['random']:.2f} | {r['fixed 30/30 axial']:.2f} | "
            f"{r['fixed 45/45 diagonal']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 materials, 2 random draws each")
    args = ap.parse_args(argv)
    t0 = time.time()
    prior = P.default_prior().astype(jnp.float64)
    names, models, refs, _ = merl_split("test")
    keep = list(range(0, len(names), 7)) if args.quick else list(range(len(names)))
    draws = 2 if args.quick else 3
    models = jax.tree_util.tree_map(lambda x: x[np.asarray(keep)], models)
    rows = run([names[k] for k in keep], models, np.asarray(refs)[keep], prior, draws)
    out = dict(machine(), quick=args.quick, draws=draws, samples=SAMPLES)
    out |= dict(rows=rows, summary=summary(rows))
    out |= dict(load_average=load_average(), seconds=time.time() - t0)
    stem = "suggest_quick" if args.quick else "suggest"
    write_json(f"{stem}.json", out)
    (RESULTS / f"{stem}.md").write_text(markdown(out))
    chart(out, RESULTS / f"{stem}.png")
    _log(markdown(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
