"""The learned models on a whole BTF (issue 14, "folder and BTF runs use it ... measure it").

Run: ``python -m benchmarks.btf_learned [--size N]`` (default 128² texels) → ``results/
btf_learned.{json,md}``.

A procedural BTF (``abrdf_jax.btf.generate_btf``, seed 1, 204 samples a texel, the reference
beside it) is reconstructed by ``reconstruct_btf`` (what ``abrdf-jax btf reconstruct`` runs) with
``model="fixed"`` (the default RBF operator), ``"prior"`` and ``"fused"`` (the package's default
prior, one matrix product per chunk, :mod:`abrdf_jax.btf`), float16 store, chunks of 1024 texels,
all in this process: each model once cold (its chunk map built and compiled) and once warm into a
new folder; wall seconds, texels per second and the busy seconds of the compute stage, and the
mean ΔE76 / LogErr over every 16th texel against the reference. The procedural material is
anisotropic (self-shadowing of a height field), unlike the prior's isotropic database: the
accuracy column says what a user gets on such a texture, the time column the throughput class.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ._common import RESULTS, machine, write_json

MODELS = ("fixed", "prior", "fused")
CHUNK = 1024


def _errors(store, ref) -> dict:
    from abrdf_jax.metrics import evaluate_batch

    idx = np.arange(0, store.n_texels, 16)
    rec = store.read().reshape(-1, 81, 81, 3)[idx].astype(np.float32)
    truth = ref.read().reshape(-1, 81, 81, 3)[idx].astype(np.float32)
    per = evaluate_batch(rec, truth)
    return {k: float(np.mean(np.asarray(per[k]))) for k in ("de76", "logerr")}


def run(size: int, log=print) -> dict:
    from abrdf_jax import btf

    out = {}
    with tempfile.TemporaryDirectory(prefix="btf-learned-") as tmp:
        paths = btf.generate_btf(Path(tmp) / "gen", size, seed=1, chunk=CHUNK)
        ref = btf.ChunkedStore.open(paths["reference"])
        for model in MODELS:
            row = {}
            for state in ("cold", "warm"):
                stats: dict = {}
                t = time.perf_counter()
                store = btf.reconstruct_btf(
                    paths["measurements"], Path(tmp) / f"{model}-{state}", chunk=CHUNK,
                    progress=False, dtype="float16", model=model, stats=stats,
                )  # fmt: skip
                s = time.perf_counter() - t
                row[state] = {
                    "seconds": s,
                    "texels_per_second": store.n_texels / s,
                    "compute_seconds": stats["compute_seconds"],
                    "build_seconds": stats["build_seconds"],
                    "backend": stats["backend"],
                }
            row |= _errors(store, ref)
            log(
                f"{model:6s} cold {row['cold']['seconds']:.1f} s, warm {row['warm']['seconds']:.2f}"
                f" s ({row['warm']['texels_per_second']:.0f} texels/s), dE76 {row['de76']:.2f}"
            )
            out[model] = row
    return out


def markdown(payload: dict) -> str:
    n = payload["size"]
    lines = [
        f"# Learned models on a {n}x{n} BTF (`python -m benchmarks.btf_learned --size {n}`)",
        "",
        f"{payload['machine'].get('date')}, load {payload['load_before']} → "
        f"{payload['load_after']}, {payload['seconds']:.0f} s. `reconstruct_btf`, float16 store, "
        f"chunks of {CHUNK}; ΔE76 / LogErr: mean over every 16th texel against the reference.",
        "",
        "| model | backend | cold s | warm s | warm texels/s | warm compute s | ΔE76 | LogErr |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for model, r in payload["models"].items():
        w = r["warm"]
        lines.append(
            f"| {model} | {w['backend']} | {r['cold']['seconds']:.1f} | {w['seconds']:.2f} | "
            f"{w['texels_per_second']:,.0f} | {w['compute_seconds']:.2f} | {r['de76']:.2f} | "
            f"{r['logerr']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128, help="texels per side (default 128)")
    args = ap.parse_args(argv)
    t0 = time.time()
    load_before = [round(x, 2) for x in os.getloadavg()]
    models = run(args.size)
    payload = dict(
        machine=machine(),
        size=args.size,
        load_before=load_before,
        load_after=[round(x, 2) for x in os.getloadavg()],
        seconds=time.time() - t0,
        models=models,
    )
    write_json("btf_learned.json", payload)
    md = markdown(payload)
    (RESULTS / "btf_learned.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
