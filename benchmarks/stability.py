"""Numerical edges of the reconstruction: where each method fails, measured (issue 5).

Run: ``python -m benchmarks.stability [--quick]`` (full: about 10 minutes on 2 loaded CPU cores;
``--quick``: a few points per sweep, about 3 minutes). Writes ``benchmarks/results/stability.json``
and ``stability.md`` (``stability_quick.*`` with ``--quick``) and the charts
``stability_condition.png``, ``stability_width.png``, ``stability_noise.png``,
``stability_anisotropy.png``, ``stability_eq4.png`` (docs/stability.md, "Numerical edges").

1. **RBF conditioning.** The iso102 RBF system (1296 centres, onion coordinates) for each kernel
   family in float32 and float64, over kernel widths and regularisation λ: the estimated 1-norm
   condition number (the guard's Hager estimate; in float64 also the exact one, to check the
   estimator), whether the plain solve is singular to working precision, NaN in the tables,
   ΔE76 of the reconstruction with the guard off and on, and how far float32 is from float64.
2. **Data edges** through the four methods (paper/recommended settings × iso102/aniso204):
   all-zero and constant materials, a chrome-like peak ~10⁴ above the diffuse level, negative
   and NaN samples, duplicated and nearly duplicated samples, few samples per slice, a missing
   elevation pair or slice, α at 0 and 90°, noise, anisotropy strength and axis rotation.
3. **Method failures.** The eq. (4) min–max remap (rule ``filip2012``) against the other
   subspace rules as one slice's specular peak comes to dominate the dynamic range; the
   isotropic shortcut (iso102) on anisotropic data. The PCA prior and the analytic-model fits
   live on another branch and are not measured here.

Materials: the package's analytic models (``abrdf_jax.materials``) and, when the shared data
folder is there, six MERL/Nielsen test-split networks (isotropic, measured). References are the
dense 81×81 tables of the same models; errors are the protocol's ΔE76 (``abrdf_jax.metrics``).

Parts, one file each: ``_stability_common`` (the methods, the guarded and plain reconstruction, the
RBF system's diagnostics, materials), ``_stability_rbf`` (1), ``_stability_data`` (2 and 3),
``_stability_report`` (charts, markdown); this module is the command line.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from ._common import RESULTS, machine, write_json
from ._stability_common import METHODS, log, materials_iso
from ._stability_data import anisotropy, data_edges, eq4
from ._stability_rbf import breaks, conditioning
from ._stability_report import charts, markdown

__all__ = [
    "METHODS",
    "anisotropy",
    "breaks",
    "charts",
    "conditioning",
    "data_edges",
    "eq4",
    "main",
    "markdown",
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few points per sweep (smoke run)")
    ap.add_argument(
        "--data-dir", default=None, help="shared data folder (default: the package's lookup)"
    )
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # float64 is needed for the f32/f64 comparison
    t0 = time.time()
    rng = np.random.default_rng(0)
    names, models, refs = materials_iso(args.data_dir, 2 if args.quick else 4)
    cond_rows = conditioning(args.quick, names, models, refs)
    payload = dict(
        machine=machine(),
        quick=args.quick,
        materials=names,
        conditioning=cond_rows,
        breaks=breaks(cond_rows),
    )
    payload["data_edges"] = data_edges(args.quick, models, refs, rng)
    payload["anisotropy"] = anisotropy(args.quick)
    payload["eq4"] = eq4(args.quick)
    payload["seconds"] = time.time() - t0
    suffix = "_quick" if args.quick else ""
    payload["charts"] = charts(payload, suffix)
    write_json(f"stability{suffix}.json", payload)
    (RESULTS / f"stability{suffix}.md").write_text(markdown(payload))
    log(
        f"wrote benchmarks/results/stability{suffix}.json, .md and {len(payload['charts'])} charts "
        f"in {payload['seconds']:.0f} s"
    )


if __name__ == "__main__":
    main()
