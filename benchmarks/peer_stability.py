"""Where the peers fail: the analytic fit's instability on anisotropic data, and the PCA prior's reach.

Run: ``python -m benchmarks.peer_stability [--quick]``. Writes ``benchmarks/results/peer_stability.json``
and ``peer_stability.md`` (quick: ``_quick``); ``docs/stability.md`` quotes the full run.

The paper (Filip 2012, sec. 1) reports unstable fits of anisotropic analytic models to sparse
slice data. This reproduces it with the analytic peer of ``benchmarks/analytic_peer.py`` (GGX +
Lambert, Levenberg–Marquardt of optimistix on log residuals, 10 parameters): every start of the
peer's start grid is fitted *separately* to the aniso204 slices of anisotropic GGX materials (known
parameters) at several anisotropy ratios and tangent-frame angles, and for each start we report
the final sample loss, the dense ΔE76 of the fit, and the fitted anisotropy ratio and angle against
the truth, without noise and with 5 % multiplicative noise; and the same for the package's named
anisotropic materials (Ward, Ashikhmin–Shirley, grooved and fabric models: outside the peer's family,
so the fit is a projection, as on measured data). Unstable means: starts that end with nearly the same sample loss (within 10 % of the
best) disagree on the dense error or on the orientation, i.e. the slices do not determine the model.

The PCA prior (``benchmarks/pca_peer.py``) is trained on the isotropic MERL database; its failure is
representational, measured in the suite (``suite.md``, table ``analytic-aniso``) and quoted here.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import GGX, dense_table, get_material
from abrdf_jax.metrics import evaluate_batch

from ._common import RESULTS, machine, write_json
from .analytic_peer import _ANISO_STARTS, _grid_tables, _problem, _solve, _starts, unpack

MODEL = "ggx"
EPS_REL = 1e-3  # the peer's choice on the train split (analytic_peer.SELECTED)


NAMED = (
    "ward-brushed-steel",
    "ward-rotated-45",
    "ashikhmin-satin",
    "ggx-aniso-metal",
    "rough-fabric",
    "rough-grooves",
)
NOISE = (0.0, 0.05)


def materials(quick: bool) -> dict:
    """``{name: (model, true ratio or None, true angle or None)}``: GGX (the peer's own family, known
    parameters) and the package's named anisotropic materials (other families: a model mismatch)."""
    ratios = (1.5, 4.0) if quick else (1.5, 2.0, 4.0, 8.0)
    angles = (0.0, 30.0) if quick else (0.0, 30.0, 60.0)
    out = {n: (get_material(n), None, None) for n in (NAMED[:2] if quick else NAMED)}
    for r in ratios:
        for a in angles:
            out[f"ggx r={r:g} φ={a:g}°"] = (
                GGX(
                    diffuse=[0.08, 0.2, 0.4],
                    specular_f0=[0.5, 0.45, 0.4],
                    alpha_x=0.08,
                    alpha_y=0.08 * r,
                    rotation=np.deg2rad(a),
                ),
                r,
                a,
            )
    return out


@jax.jit
def _per_start(y, valid, wi, wv):
    target, eps, w = _problem(y, valid, jnp.asarray(EPS_REL, y.dtype))
    starts = _starts(MODEL, True, y, valid, wi, wv, y.dtype)
    theta, loss, steps = jax.vmap(lambda t0: _solve(t0, target, eps, w, wi, wv, MODEL, True, 100))(
        starts
    )
    return theta, loss, steps


def _angle_error(fit_ax, fit_ay, fit_rot, true_rot_deg):
    """Angle between the fitted and the true long axis (degrees, in [0, 90]); the long axis is
    x + rotation if αx > αy, else rotation + 90°; orientation is defined modulo 180°."""
    long_fit = np.rad2deg(fit_rot) + np.where(fit_ax > fit_ay, 0.0, 90.0)
    long_true = true_rot_deg + 90.0  # the materials have αy > αx
    d = np.abs((long_fit - long_true + 90.0) % 180.0 - 90.0)
    return d


def _orientation_spread(ax, ay, rot) -> float:
    """Largest angle (degrees, modulo 180°) between the long axes of several fits whose anisotropy
    is at least 10 % (isotropic fits have no axis and are left out)."""
    keep = np.maximum(ax, ay) / np.minimum(ax, ay) > 1.1
    if keep.sum() < 2:
        return 0.0
    axis = (np.rad2deg(rot) + np.where(ax > ay, 0.0, 90.0))[keep] % 180.0
    d = np.abs((axis[:, None] - axis[None, :] + 90.0) % 180.0 - 90.0)
    return float(d.max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4 materials instead of 12")
    args = ap.parse_args(argv)
    t_start = time.time()
    rows = []
    rng = np.random.default_rng(0)
    config = aj.Config(budget="aniso204")
    params = aj.Params.default(config)
    for (name, (model, ratio, angle)), sigma in (
        (m, s) for m in materials(args.quick).items() for s in NOISE
    ):
        meas = aj.sample(model, config, params, as_measurements=True)
        if sigma:
            noisy = meas.y * (1 + sigma * rng.standard_normal(meas.y.shape))
            meas = meas.replace(y=jnp.maximum(noisy, 0.0).astype(meas.y.dtype))
        name_s = f"{name}, {int(np.sum(np.asarray(meas.count)))} samples, σ={sigma:g}"
        wi, wv = aj.slice_directions(meas.t, meas.pairs, params.alpha.astype(meas.y.dtype))
        s, n = wi.shape[0], wi.shape[1]
        y = meas.y.reshape(s * n, 3)
        valid = meas.mask.reshape(s * n)
        theta, loss, steps = _per_start(y, valid, wi.reshape(-1, 3), wv.reshape(-1, 3))
        tables = _grid_tables(theta, MODEL, True)
        ref = jnp.asarray(dense_table(model))[None]
        de = np.asarray(evaluate_batch(tables, jnp.broadcast_to(ref, tables.shape))["de76"])
        p = jax.vmap(lambda t: unpack(t, MODEL, True))(theta)
        ax, ay, rot = (np.asarray(p[k]) for k in ("alpha_x", "alpha_y", "rotation"))
        ratio_fit = np.maximum(ax, ay) / np.minimum(ax, ay)
        ang = _angle_error(ax, ay, rot, angle) if angle is not None else np.full(len(ax), np.nan)
        loss = np.asarray(loss)
        best = int(np.argmin(loss))
        near = loss <= 1.1 * loss[best]
        rows.append(
            dict(
                material=name_s,
                noise=sigma,
                samples=int(np.sum(np.asarray(meas.count))),
                ratio=ratio,
                angle=angle,
                loss=loss.tolist(),
                de76=de.tolist(),
                ratio_fit=ratio_fit.tolist(),
                angle_error=ang.tolist(),
                steps=np.asarray(steps).tolist(),
                best=best,
                near_best=int(near.sum()),
                de76_best=float(de[best]),
                de76_spread_near=float(de[near].max() - de[near].min()),
                angle_spread_near=float(np.nanmax(ang[near]) - np.nanmin(ang[near]))
                if angle is not None
                else None,
                orientation_spread_near=float(_orientation_spread(ax[near], ay[near], rot[near])),
                angle_error_best=float(ang[best]),
                ratio_fit_best=float(ratio_fit[best]),
                finite=bool(np.all(np.isfinite(loss))),
            )
        )
        r = rows[-1]
        print(
            f"{name_s:34s} best loss {loss[best]:.4f}: ΔE76 {de[best]:.2f}, ratio {ratio_fit[best]:.2f} (true {ratio}), "
            f"axis off by {ang[best]:.1f}°; {r['near_best']} of {len(loss)} starts within 10 % of the best loss, "
            f"their ΔE76 spread {r['de76_spread_near']:.2f}, long-axis spread {r['orientation_spread_near']:.1f}°",
            flush=True,
        )
    out = dict(
        machine=machine(),
        quick=args.quick,
        model=MODEL,
        eps_rel=EPS_REL,
        starts=[list(map(float, s)) for s in _ANISO_STARTS],
        rows=rows,
        seconds=time.time() - t_start,
    )
    suffix = "_quick" if args.quick else ""
    write_json(f"peer_stability{suffix}.json", out)
    lines = [
        "# Analytic peer (GGX + Lambert, LM) on anisotropic GGX materials, aniso204 slices, each start fitted alone",
        "",
        f"`python -m benchmarks.peer_stability{' --quick' if args.quick else ''}`, {out['machine']['date']}, "
        f"{len(_ANISO_STARTS)} starts per material (`analytic_peer._ANISO_STARTS`).",
        "",
        "| material, samples, noise | best start: ΔE76 | fitted ratio | axis error | starts within 10 % of the best loss | their ΔE76 spread | their long-axis spread | all starts: ΔE76 min–max |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        true = "?" if r["ratio"] is None else f"{r['ratio']:g}"
        axis = "–" if r["angle"] is None else f"{r['angle_error_best']:.1f}°"
        lines.append(
            f"| {r['material']} | {r['de76_best']:.2f} | {r['ratio_fit_best']:.2f} (true {true}) | "
            f"{axis} | {r['near_best']} / {len(r['loss'])} | {r['de76_spread_near']:.2f} | "
            f"{r['orientation_spread_near']:.1f}° | {min(r['de76']):.2f}–{max(r['de76']):.2f} |"
        )
    (RESULTS / f"peer_stability{suffix}.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS / f'peer_stability{suffix}.md'} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
