"""How tight the learned models' ceiling may be (issue 14; ``abrdf_jax.prior.CEILING_MARGIN``).

Run: ``python -m benchmarks.prior_ceiling [--size N]`` → ``results/prior_ceiling.{json,md}``.

A learned reconstruction is clipped at ``ceiling + margin`` in the prior's mapped space, the
ceiling being the largest mapped training value of each direction pair
(:func:`abrdf_jax.prior.below_ceiling`). The margin trades two failures:

- too tight, it clips real values: the fraction of dense-truth values above ``ceiling + margin``
  of the package's default prior, on the 108 measured tables of ``../shared/data`` (MERL and
  Nielsen neural fits, train and test split: values the default prior, trained on analytic
  materials only, never saw) and on the 8 built-in analytic materials;
- too loose, it lets an extrapolation through: on a procedural BTF (``generate_btf``, seed 1,
  anisotropic, self-shadowed; ``--size`` texels per side) reconstructed with the fused model
  and no clip, then clipped at each margin in the mapped space: the fraction of texels whose
  table's maximum exceeds 100 times their largest sample (the truth's own largest ratio is
  about 50), the largest such ratio and the mean ΔE76 over every 16th texel.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from ._common import timed_run

MARGINS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, None)
OVERSHOOT = 100.0


def _grid(prior):
    """``(x_ref, cos θv)`` on the grid, columns to broadcast against ``(N, 6561, 3)`` values."""
    from abrdf_jax.prior import grid_cos_view

    return np.asarray(prior.reference, np.float64)[:, :1], grid_cos_view()[:, None]


def _mapped(prior, x):
    from abrdf_jax.prior import log_relative

    x = np.asarray(x, np.float64).reshape(len(x), 6561, 3)
    return log_relative(x, *_grid(prior), prior.eps)


def _unmapped(prior, m):
    from abrdf_jax.prior import inverse_log_relative

    return inverse_log_relative(m, *_grid(prior), prior.eps)


def truth_above(prior, tables, names) -> list[dict]:
    """Per margin: the fraction of truth values above ``ceiling + margin``, the materials
    with any, the worst one."""
    m = _mapped(prior, tables)
    ceiling = np.asarray(prior.ceiling, np.float64)[:, None]
    rows = []
    for margin in MARGINS[:-1]:
        over = (m > ceiling + margin).reshape(len(m), -1).mean(axis=1)
        worst = int(np.argmax(over))
        rows.append(
            {
                "margin": margin,
                "fraction": float(over.mean()),
                "materials_with_any": int(np.sum(over > 0)),
                "worst": names[worst],
                "worst_fraction": float(over[worst]),
            }
        )
    return rows


def btf_rows(prior, size: int) -> list[dict]:
    """The fused model on a procedural BTF, unclipped and clipped at each margin."""
    import equinox as eqx
    import jax.numpy as jnp

    from abrdf_jax import btf
    from abrdf_jax.metrics import evaluate_batch

    free = eqx.tree_at(lambda p: p.ceiling, prior, None, is_leaf=lambda x: x is None)
    with tempfile.TemporaryDirectory(prefix="prior-ceiling-") as tmp:
        paths = btf.generate_btf(Path(tmp) / "gen", size, seed=1, chunk=1024)
        store = btf.reconstruct_btf(
            paths["measurements"], Path(tmp) / "fused", chunk=1024, progress=False,
            dtype="float32", model="fused", prior=free,
        )  # fmt: skip
        x = store.read().reshape(store.n_texels, 6561, 3)
        truth = btf.ChunkedStore.open(paths["reference"]).read().reshape(-1, 81, 81, 3)
        top = btf.ChunkedStore.open(paths["measurements"]).read().reshape(len(x), -1).max(1)
    idx = np.arange(0, len(x), 16)
    m = _mapped(prior, x)
    ceiling = np.asarray(prior.ceiling, np.float64)[:, None]
    rows = []
    for margin in MARGINS:
        y = x if margin is None else _unmapped(prior, np.minimum(m, ceiling + margin))
        ratio = y.reshape(len(y), -1).max(axis=1) / np.maximum(top, 1e-30)
        per = evaluate_batch(
            jnp.asarray(y[idx].reshape(-1, 81, 81, 3), jnp.float32),
            jnp.asarray(truth[idx], jnp.float32),
        )
        rows.append(
            {
                "margin": margin,
                "de76": float(np.mean(np.asarray(per["de76"]))),
                "logerr": float(np.mean(np.asarray(per["logerr"]))),
                "overshoot_fraction": float(np.mean(ratio > OVERSHOOT)),
                "max_peak_ratio": float(ratio.max()),
            }
        )
    return rows


def run(size: int, log=print) -> dict:
    from abrdf_jax import materials
    from abrdf_jax.prior import CEILING_MARGIN, default_prior

    prior = default_prior()
    t = materials.load_tables81()
    names = [str(n) for n in t["names"]]
    measured = truth_above(prior, t["abrdf"], names)
    analytic_names = list(materials.material_names())
    analytic = np.stack([materials.dense_table(n) for n in analytic_names])
    out = {
        "margin_in_use": CEILING_MARGIN,
        "measured": measured,
        "analytic": truth_above(prior, analytic, analytic_names),
        "btf": btf_rows(prior, size),
    }
    for r in out["btf"]:
        log(
            f"margin {r['margin']}: BTF dE76 {r['de76']:.3f}, overshoot {r['overshoot_fraction']:.2%}"
        )
    return out


def _margin(m) -> str:
    return "none (no clip)" if m is None else f"{m:g}"


def markdown(p: dict) -> str:
    lines = [
        "# The learned models' ceiling (issue 14)",
        "",
        f"`python -m benchmarks.prior_ceiling --size {p['size']}` on {p['machine']['platform']},"
        f" {p['machine']['date']} ({p['seconds']:.0f} s). The margin in use: "
        f"{p['results']['margin_in_use']:g}. Truth values above the default prior's ceiling + "
        "margin (too tight: clips real values):",
        "",
        "| margin | measured tables (108): values above | materials with any | worst "
        "| analytic (8): values above | materials with any | worst |",
        "|---|---|---|---|---|---|---|",
    ]
    for a, b in zip(p["results"]["measured"], p["results"]["analytic"]):
        lines.append(
            f"| {_margin(a['margin'])} | {a['fraction']:.4%} | {a['materials_with_any']} | "
            f"{a['worst']} ({a['worst_fraction']:.2%}) | {b['fraction']:.4%} | "
            f"{b['materials_with_any']} | {b['worst']} ({b['worst_fraction']:.2%}) |"
        )
    lines += [
        "",
        f"The fused model on a {p['size']}² procedural BTF (too loose: lets an extrapolation "
        f"through; overshoot: a texel's maximum above {OVERSHOOT:g}× its largest sample):",
        "",
        "| margin | ΔE76 | LogErr | overshooting texels | largest ratio |",
        "|---|---|---|---|---|",
    ]
    for r in p["results"]["btf"]:
        lines.append(
            f"| {_margin(r['margin'])} | {r['de76']:.3f} | {r['logerr']:.4f} | "
            f"{r['overshoot_fraction']:.2%} | {r['max_peak_ratio']:.3g} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=64, help="BTF texels per side (default 64)")
    args = ap.parse_args(argv)
    timed_run("prior_ceiling", lambda: run(args.size), markdown, size=args.size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
