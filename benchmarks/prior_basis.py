"""The learned models' basis at the samples: interpolated from the grid or exact (issues 12, 14).

Run: ``python -m benchmarks.prior_basis`` → ``results/prior_basis.json`` and ``.md``.

Every 4th MERL test material (14), captured by :func:`abrdf_jax.simulate_capture` (iso102, seed
``12 + i``, no noise) with the protocol's counts and with 200 samples per slice, grouped by
:func:`abrdf_jax.group_slices`; each reconstructed by the command line's numpy operators
(:func:`abrdf_jax.compile_numpy_operator`) of the default prior alone and of the fused model, once
with the prior as it is (its basis at the exact sample directions, docs/prior.md "The basis at
the samples") and once with the same prior without its ``weights`` (the basis interpolated from
the grid tables, as before); mean ΔE76 against ``materials.dense_table``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics
from abrdf_jax import prior as P

from ._common import RESULTS, load_average, machine, write_json

CAPTURES = {"protocol": {}, "200 per slice": {"per_slice": 200}}


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


def main(argv=None) -> int:
    t0 = time.time()
    load0 = load_average()
    exact = P.default_prior()
    grid_only = P.Prior(
        exact.mean, exact.components, exact.reference, exact.lam,
        eps=exact.eps, channels=exact.channels, meta=exact.meta,
    )  # fmt: skip
    bases = {"exact": exact, "interpolated": grid_only}
    names = materials.merl_split("test")[::4]
    mats = {n: materials.get_material("nbrdf:" + n) for n in names}
    refs = {n: np.asarray(materials.dense_table(m), np.float32) for n, m in mats.items()}
    rows = []
    for cap, kw in CAPTURES.items():
        meas = [
            aj.group_slices(aj.simulate_capture(m, budget="iso102", seed=12 + i, **kw))[0]
            for i, m in enumerate(mats.values())
        ]
        for basis, prior in bases.items():
            for model, fused in (("prior", False), ("fused", True)):
                de = []
                for m, n in zip(meas, names):
                    op = aj.compile_numpy_operator(prior, m, budget="iso102", fused=fused)
                    t = np.asarray(op.apply(np.asarray(m.y)), np.float32)
                    de.append(float(metrics.evaluate(t, refs[n])["de76"]))
                rows.append(dict(capture=cap, basis=basis, model=model, de76=float(np.mean(de))))
                _log(f"{cap:14s} {basis:12s} {model:6s} mean dE76 {rows[-1]['de76']:.3f}")
    out = dict(machine(), load_before=load0, load_after=load_average())
    out |= dict(materials=list(names), rows=rows, seconds=time.time() - t0)
    write_json("prior_basis.json", out)
    lines = [
        "# The learned models' basis at the samples (`python -m benchmarks.prior_basis`)",
        "",
        f"Load {out['load_before']} / {out['load_after']}, {out['seconds']:.0f} s. "
        f"{len(names)} MERL test materials, iso102 captures, default prior; mean ΔE76.",
        "",
        "| capture | basis | prior only | fused |",
        "|---|---|---|---|",
    ]
    for cap in CAPTURES:
        for basis in bases:
            v = {r["model"]: r["de76"] for r in rows if (r["capture"], r["basis"]) == (cap, basis)}
            lines.append(f"| {cap} | {basis} | {v['prior']:.2f} | {v['fused']:.2f} |")
    (RESULTS / "prior_basis.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
