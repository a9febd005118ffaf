"""The learned models on a whole BTF (issue 14, "folder and BTF runs use it ... measure it").

Run: ``python -m benchmarks.btf_learned [--size N]`` (default 128² texels) → ``results/
btf_learned.{json,md}``.

A procedural BTF (``abrdf_jax.btf.generate_btf``, seed 1, 204 samples a texel, the reference
beside it) is reconstructed by ``reconstruct_btf`` (what ``abrdf-jax btf reconstruct`` runs) with
``model="fixed"`` (the default RBF operator), ``"prior"`` and ``"fused"`` (the package's default
prior, one matrix product per chunk, :mod:`abrdf_jax.btf`), float32 store (a learned model's
overshoot can exceed float16's range), chunks of 1024 texels,
all in this process: each model once cold (its chunk map built and compiled) and once warm into a
new folder; wall seconds, texels per second and the busy seconds of the compute stage, and the
mean ΔE76 / LogErr over every 16th texel against the reference, and the fraction of texels whose
table's maximum exceeds 100 times their largest sample (overshoot), with the overshooting texels'
largest excursion above the learned model's prior mean in its prior standard deviations (inside
or outside the model's own envelope). The procedural material is
anisotropic (self-shadowing of a height field), unlike the prior's isotropic database: the
accuracy column says what a user gets on such a texture, the time column the throughput class.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from ._common import timed_run

MODELS = ("fixed", "prior", "fused")
CHUNK = 1024


#: A texel "overshoots" where its table's maximum exceeds this multiple of its largest sample
#: (the procedural truth's own ratio is at most about 50).
OVERSHOOT = 100.0


def _sigmas(store, texels, model: str) -> float | None:
    """The largest excursion of the overshooting ``texels``' tables above the learned model's
    prior mean, in prior standard deviations of the mapped space (``σ_p² ‖Q_g‖² + σ_k²`` for
    the fused model, ``‖Q_g‖²`` for the prior alone): whether the overshoot stays inside the
    model's own prior envelope. ``None`` for the RBF model or without overshoot."""
    if model == "fixed" or texels.size == 0:
        return None
    from abrdf_jax.prior import FUSED_DEFAULTS, default_prior, grid_cos_view, log_relative

    prior = default_prior()
    q, mu = np.asarray(prior.components, np.float64), np.asarray(prior.mean, np.float64)
    fused = {**FUSED_DEFAULTS, **prior.metadata.get("fused", {})}
    sp, sk = (fused["sigma_p"], fused["sigma_k"]) if model == "fused" else (1.0, 0.0)
    sd = np.sqrt(sp**2 * np.sum(q**2, axis=1) + sk**2)  # (6561,) shared channels
    ref, cos, eps = np.asarray(prior.reference, np.float64)[:, 0], grid_cos_view(), prior.eps
    x = store.read().reshape(store.n_texels, -1, 3)[texels].astype(np.float64)
    m = log_relative(x, ref[:, None], cos[:, None], eps)
    return float(np.max((m - mu[:, None]) / sd[:, None]))


def _errors(store, ref, meas, model: str) -> dict:
    from abrdf_jax.metrics import evaluate_batch

    idx = np.arange(0, store.n_texels, 16)
    rec = store.read().reshape(-1, 81, 81, 3)[idx].astype(np.float32)
    truth = ref.read().reshape(-1, 81, 81, 3)[idx].astype(np.float32)
    per = evaluate_batch(rec, truth)
    out = {k: float(np.mean(np.asarray(per[k]))) for k in ("de76", "logerr")}
    peak = store.read().reshape(store.n_texels, -1).max(axis=1)
    ratio = peak / np.maximum(meas.read().reshape(store.n_texels, -1).max(axis=1), 1e-30)
    truth_ratio = ref.read().reshape(store.n_texels, -1).max(axis=1).astype(np.float64)
    truth_ratio /= np.maximum(meas.read().reshape(store.n_texels, -1).max(axis=1), 1e-30)
    over = np.flatnonzero(ratio > OVERSHOOT)
    return out | {
        "overshoot_fraction": float(np.mean(ratio > OVERSHOOT)),
        "overshoot_prior_sigmas": _sigmas(store, over, model),
        "max_peak_ratio": float(ratio.max()),
        "truth_overshoot_fraction": float(np.mean(truth_ratio > OVERSHOOT)),
        "truth_max_peak_ratio": float(truth_ratio.max()),
    }


def run(size: int, log=print) -> dict:
    from abrdf_jax import btf

    out = {}
    with tempfile.TemporaryDirectory(prefix="btf-learned-") as tmp:
        paths = btf.generate_btf(Path(tmp) / "gen", size, seed=1, chunk=CHUNK)
        ref = btf.ChunkedStore.open(paths["reference"])
        meas = btf.ChunkedStore.open(paths["measurements"])
        for model in MODELS:
            row = {}
            for state in ("cold", "warm"):
                stats: dict = {}
                t = time.perf_counter()
                store = btf.reconstruct_btf(
                    paths["measurements"], Path(tmp) / f"{model}-{state}", chunk=CHUNK,
                    progress=False, dtype="float32", model=model, stats=stats,
                )  # fmt: skip
                s = time.perf_counter() - t
                row[state] = {
                    "seconds": s,
                    "texels_per_second": store.n_texels / s,
                    "compute_seconds": stats["compute_seconds"],
                    "build_seconds": stats["build_seconds"],
                    "backend": stats["backend"],
                }
            row |= _errors(store, ref, meas, model)
            log(
                f"{model:6s} cold {row['cold']['seconds']:.1f} s, warm {row['warm']['seconds']:.2f}"
                f" s ({row['warm']['texels_per_second']:.0f} texels/s), dE76 {row['de76']:.2f}, "
                f"overshoot {100 * row['overshoot_fraction']:.1f}% of texels"
            )
            out[model] = row
    return out


def markdown(payload: dict) -> str:
    n = payload["size"]
    first = next(iter(payload["models"].values()))
    lines = [
        f"# Learned models on a {n}x{n} BTF (`python -m benchmarks.btf_learned --size {n}`)",
        "",
        f"{payload['machine'].get('date')}, load {payload['load_before']} → "
        f"{payload['load_after']}, {payload['seconds']:.0f} s. `reconstruct_btf`, float32 store, "
        f"chunks of {CHUNK}; ΔE76 / LogErr: mean over every 16th texel against the reference; "
        f"overshoot: texels whose table's maximum exceeds {OVERSHOOT:g}× their largest sample "
        "(the largest such ratio beside it; the reference itself: "
        f"{100 * first['truth_overshoot_fraction']:.1f} % of texels, largest ratio "
        f"{first['truth_max_peak_ratio']:.1f}).",
        "",
        "| model | backend | cold s | warm s | warm texels/s | warm compute s | ΔE76 | LogErr "
        "| overshoot (largest ratio) | overshoot in prior σ (largest) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for model, r in payload["models"].items():
        w = r["warm"]
        lines.append(
            f"| {model} | {w['backend']} | {r['cold']['seconds']:.1f} | {w['seconds']:.2f} | "
            f"{w['texels_per_second']:,.0f} | {w['compute_seconds']:.2f} | {r['de76']:.2f} | "
            f"{r['logerr']:.3f} | {100 * r['overshoot_fraction']:.1f} % "
            f"({r['max_peak_ratio']:.3g}) | {_f(r.get('overshoot_prior_sigmas'))} |"
        )
    return "\n".join(lines) + "\n"


def _f(x) -> str:
    return "–" if x is None else f"{x:.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128, help="texels per side (default 128)")
    args = ap.parse_args(argv)
    timed_run("btf_learned", lambda: run(args.size), markdown, key="models", size=args.size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
