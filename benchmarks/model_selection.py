"""Automatic model selection: isotropy decisions, the automatic choice's error, selection cost.

Run: ``python -m benchmarks.model_selection [--quick]``. Writes
``benchmarks/results/model_selection.json`` (``model_selection_quick.json``), the README table
``model_selection.md`` and the chart ``model_selection.png`` (``_quick`` variants in quick mode).

1. **Confusion table** of the isotropy decision (``abrdf_jax.select.isotropy_test``) and of the
   final automatic choice (``select_model``: the test, then held-out error with the 5 % rule):
   - truly isotropic: the MERL/Nielsen *test* split, sampled with the anisotropic budget
     (aniso204, so that the axial slices exist), at several levels of multiplicative Gaussian
     noise ``y · (1 + σ n)``;
   - truly anisotropic: the analytic Ward and GGX models at anisotropy ratios
     ``alpha_y / alpha_x`` from nearly isotropic to strong (and the package's named anisotropic
     materials), at the same noise levels. For these the table also says whether the
     anisotropic model *materially* lowers the dense error (ΔE76 at least 5 % below the
     bivariate model's, what an isotropic verdict gets, against the noise-free dense table): the
     decision that matters.
2. **Error of the automatic choice** on the MERL test split (noise-free samples) beside every
   fixed model of the candidate list: mean ΔE76 and LogErr against the dense reference tables.
3. **Error against complexity**: mean dense ΔE76 and mean held-out (cross-validated) log error
   of each candidate against its complexity rank, MERL test and the analytic set (the chart).
4. **Cost**: ``select_model`` per material beside ``reconstruct`` per material (after
   compilation; both compile times apart), float32 on CPU.
5. **The prior-only model among the candidates** (``benchmarks/_selection_prior.py``): the
   choice with the default prior, MERL test and the built-in materials.

Nothing here is tuned on the test split: the candidates, thresholds (level 1e-3, minimum effect
0.02) and the tolerance (5 %) are the package defaults.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax import select
from abrdf_jax.select import BIVARIATE, CANDIDATES, DEFAULT_ANISO, KERNEL_FAMILY, rank_of
from abrdf_jax.materials import GGX, Ward, dense_table, get_material, is_anisotropic, material_names

from . import _selection_prior
from ._selection_prior import bivariate_metrics
from ._selection_report import chart, confusion, isotropic_model, markdown
from ._common import RESULTS, machine, merl_split, metrics_of, sample_batch, write_json

NOISE = (0.0, 0.02, 0.05, 0.1)
RATIOS = (1.0, 1.25, 1.5, 2.0, 3.0, 5.0)
MATERIAL_GAIN = 0.05  # "materially lower": dense ΔE76 at least 5 % below the isotropic model's


def analytic_family(quick: bool):
    """``{name: (model, truly_isotropic)}``: Ward and GGX at several anisotropy ratios."""
    ratios = (1.0, 1.5, 3.0) if quick else RATIOS
    out = {}
    for r in ratios:
        out[f"ward a=0.15 r={r:g}"] = (
            Ward(
                diffuse=[0.05, 0.05, 0.06],
                specular=[0.3, 0.3, 0.32],
                alpha_x=0.15,
                alpha_y=0.15 * r,
            ),
            r == 1.0,
        )
        out[f"ggx a=0.15 r={r:g}"] = (
            GGX(
                diffuse=[0.08, 0.25, 0.55],
                specular_f0=[0.6, 0.5, 0.4],
                alpha_x=0.15,
                alpha_y=0.15 * r,
                rotation=np.pi / 6,
            ),
            r == 1.0,
        )
    names = [n for n in material_names() if is_anisotropic(n)]
    for n in names[: 2 if quick else None]:
        out[n] = (get_material(n), False)
    return out


def add_noise(meas: aj.Measurements, sigma: float, seed: int) -> aj.Measurements:
    if sigma == 0:
        return meas
    rng = np.random.default_rng(seed)
    y = np.asarray(meas.y) * (1.0 + sigma * rng.standard_normal(meas.y.shape))
    return meas.replace(y=jnp.asarray(y, meas.y.dtype))


def timed(fn):
    """``(fn(), seconds)``, the result blocked until ready."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0


def unstack(meas, i):
    return jax.tree_util.tree_map(lambda x: x[i], meas)


def stack(items):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *items)


def cv_errors(meas_list, names, alpha, k=4, log=print):
    """Held-out errors ``(B, len(names))`` for a list of measurements (batched per kernel group)."""
    configs = {n: CANDIDATES[n].config() for n in names}
    data = stack([select.fold_data(m, alpha, k) for m in meas_list])
    out = np.zeros((len(meas_list), len(names)))
    compile_s = 0.0
    for gnames, cfgs in select.group_configs(configs):
        params = aj.Params.default(cfgs[0], dtype=jnp.float32)
        t0 = time.perf_counter()
        errs = np.asarray(select.held_out_errors_batch(data, cfgs, params))
        compile_s += time.perf_counter() - t0
        for j, n in enumerate(gnames):
            out[:, names.index(n)] = errs[:, j]
    log(
        f"  held-out errors of {len(names)} candidates x {len(meas_list)} measurements: {compile_s:.0f} s (incl. compile)"
    )
    return out


def dense_errors(meas, ref, names, log=print):
    """``{name: {"de76": (B,), "logerr": (B,)}}`` of every fixed candidate (batched)."""
    out = {}
    for n in names:
        cfg = CANDIDATES[n].config()
        params = aj.Params.default(cfg, dtype=jnp.float32)
        t0 = time.perf_counter()
        rec = aj.reconstruct_batch(meas, cfg, params)
        m = metrics_of(rec, ref)
        out[n] = {"de76": m["de76"], "logerr": m["logerr"]}
        log(
            f"  {n:15s} dense ΔE76 {np.mean(m['de76']):6.2f}  LogErr {np.mean(m['logerr']):.3f}  ({time.perf_counter() - t0:.0f} s)"
        )
    return out


def decide(meas, cv_row, names, tol=select.TOL):
    """The automatic choice from the isotropy test and the held-out errors (as select_model:
    an isotropic material gets the bivariate model)."""
    rep = select.isotropy_test(meas)
    if rep.isotropic:
        return rep, BIVARIATE
    cand = [n for n in DEFAULT_ANISO]
    errs = {n: float(cv_row[names.index(n)]) for n in cand}
    pick, _ = select.tolerance_choice(errs, {n: CANDIDATES[n].rank for n in cand}, tol)
    return rep, pick  # among anisotropic candidates iso is the RBF


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick",
        action="store_true",
        help="12 MERL test materials, fewer analytic models and noise levels",
    )
    args = ap.parse_args(argv)
    quick = args.quick
    log = lambda s: print(s, flush=True)  # noqa: E731
    noise = (0.0, 0.05) if quick else NOISE
    cand_names = list(DEFAULT_ANISO) + (
        []
        if quick
        else [n for n in KERNEL_FAMILY if n not in DEFAULT_ANISO] + ["paper", "paper-aniso"]
    )
    alpha = np.deg2rad(aj.PROTOCOL_ALPHA_DEG)
    cfg_a = aj.Config.recommended("aniso204")
    p_a = aj.Params.default(cfg_a, dtype=jnp.float32)
    t_start = time.time()

    # -- MERL test split (isotropic) -----------------------------------------------------------
    names, models, ref, groups = merl_split("test")
    if quick:
        idx = np.linspace(0, len(names) - 1, 12).round().astype(int)
        names = [names[i] for i in idx]
        models = jax.tree_util.tree_map(
            lambda x: (
                x[idx] if hasattr(x, "shape") and x.ndim and x.shape[0] == ref.shape[0] else x
            ),
            models,
        )
        ref, groups = ref[idx], [groups[i] for i in idx]
    log(f"MERL test: {len(names)} materials, sampled aniso204")
    meas_all = sample_batch(models, cfg_a, p_a)
    merl_meas = [unstack(meas_all, i) for i in range(len(names))]
    merl_dense = dense_errors(meas_all, ref, cand_names, log)
    merl_dense[BIVARIATE] = bivariate_metrics(meas_all, ref, log)
    merl_cv = cv_errors(merl_meas, cand_names, alpha, log=log)
    merl_rows = []
    for i, n in enumerate(names):
        rep, pick = decide(merl_meas[i], merl_cv[i], cand_names)
        merl_rows.append(
            {
                "material": n,
                "group": groups[i],
                "isotropic_test": rep.isotropic,
                "statistic": rep.statistic,
                "p_value": rep.p_value,
                "effect": rep.effect,
                "noise": rep.noise,
                "choice": pick,
                "dense_de76": {c: float(merl_dense[c]["de76"][i]) for c in merl_dense},
                "dense_logerr": {c: float(merl_dense[c]["logerr"][i]) for c in merl_dense},
                "held_out": {c: float(merl_cv[i, j]) for j, c in enumerate(cand_names)},
            }
        )
    auto_de = float(np.mean([r["dense_de76"][r["choice"]] for r in merl_rows]))
    auto_le = float(np.mean([r["dense_logerr"][r["choice"]] for r in merl_rows]))
    fixed = {
        c: {
            "de76": float(np.mean(merl_dense[c]["de76"])),
            "logerr": float(np.mean(merl_dense[c]["logerr"])),
            "held_out": float(np.mean(merl_cv[:, j])),
            "rank": CANDIDATES[c].rank,
        }
        for j, c in enumerate(cand_names)
    }
    fixed[BIVARIATE] = {  # no held-out error: it is not compared (an isotropic material's model)
        "de76": float(np.mean(merl_dense[BIVARIATE]["de76"])),
        "logerr": float(np.mean(merl_dense[BIVARIATE]["logerr"])),
        "held_out": float("nan"),
        "rank": rank_of(BIVARIATE),
    }
    best = min(fixed, key=lambda c: fixed[c]["de76"])
    best_iso = min((c for c in fixed if isotropic_model(c)), key=lambda c: fixed[c]["de76"])
    log(
        f"MERL auto: ΔE76 {auto_de:.3f} (LogErr {auto_le:.4f}); best fixed {best} {fixed[best]['de76']:.3f}; "
        f"best fixed isotropic {best_iso} {fixed[best_iso]['de76']:.3f}"
    )

    # MERL under noise: the isotropy decision only (false anisotropic decisions).
    merl_noise = {}
    for s in noise:
        reps = [select.isotropy_test(add_noise(m, s, 1000 + i)) for i, m in enumerate(merl_meas)]
        merl_noise[str(s)] = {
            "isotropic": int(sum(r.isotropic for r in reps)),
            "anisotropic": int(sum(not r.isotropic for r in reps)),
            "statistic_median": float(np.median([r.statistic for r in reps])),
            "noise_estimate_median": float(np.median([r.noise for r in reps])),
        }
        log(f"  MERL noise σ={s}: isotropic {merl_noise[str(s)]['isotropic']}/{len(reps)}")

    # -- analytic models (anisotropic unless ratio 1) ----------------------------------------------
    fam = analytic_family(quick)
    log(f"analytic: {len(fam)} models x {len(noise)} noise levels")
    a_meas, a_keys, a_ref = [], [], []
    for name, (model, iso) in fam.items():
        base = aj.sample(model, cfg_a, p_a, as_measurements=True)
        table = jnp.asarray(dense_table(model))
        for j, s in enumerate(noise):
            a_meas.append(add_noise(base, s, 7 + 31 * j + len(a_keys)))
            a_keys.append((name, iso, s))
            a_ref.append(table)
    a_stack = stack(a_meas)
    a_ref = jnp.stack(a_ref)
    a_names = list(DEFAULT_ANISO)
    a_dense = dense_errors(a_stack, a_ref, a_names, log)
    a_dense[BIVARIATE] = bivariate_metrics(a_stack, a_ref, log)
    a_cv = cv_errors(a_meas, a_names, alpha, log=log)
    a_rows = []
    for i, (name, iso, s) in enumerate(a_keys):
        rep, pick = decide(a_meas[i], a_cv[i], a_names)
        de = {c: float(a_dense[c]["de76"][i]) for c in a_dense}
        best_aniso = min((c for c in a_names if c != "iso"), key=lambda c: de[c])
        gain = 1.0 - de[best_aniso] / de[BIVARIATE]  # against the model an isotropic verdict gets
        a_rows.append(
            {
                "material": name,
                "truly_isotropic": iso,
                "noise": s,
                "isotropic_test": rep.isotropic,
                "statistic": rep.statistic,
                "p_value": rep.p_value,
                "effect": rep.effect,
                "noise_estimate": rep.noise,
                "choice": pick,
                "dense_de76": de,
                "held_out": {c: float(a_cv[i, j]) for j, c in enumerate(a_names)},
                "aniso_gain": gain,
                "aniso_material": bool(gain >= MATERIAL_GAIN),
            }
        )
        log(
            f"  {name:24s} σ={s:<5g} test {'iso  ' if rep.isotropic else 'ANISO'} (stat {rep.statistic:9.3g}, effect {rep.effect:.3f}) "
            f"-> {pick:15s} ΔE76 bivariate {de[BIVARIATE]:.2f} iso {de['iso']:.2f} best aniso {de[best_aniso]:.2f} ({best_aniso}), chosen {de[pick]:.2f}"
        )

    # -- cost: select_model beside reconstruct, per material ----------------------------------------
    timing = {}
    samples = [m.to_samples() for m in merl_meas[:3]] + [a.to_samples() for a in a_meas[-3:]]
    sel, timing["select_first_s"] = timed(lambda: select.select_model(samples[-1]))
    _, timing["reconstruct_first_s"] = timed(lambda: sel.reconstruct(samples[-1]))
    sel_t, rec_t = [], []
    for s in samples:
        sel, t = timed(lambda: select.select_model(s))
        sel_t.append(t)
        rec_t.append(timed(lambda: sel.reconstruct(s))[1])
    timing.update(
        select_median_s=float(np.median(sel_t)),
        reconstruct_median_s=float(np.median(rec_t)),
        select_iso_median_s=float(np.median(sel_t[:3])),
        select_aniso_median_s=float(np.median(sel_t[3:])),
    )
    log(
        f"cost: select {timing['select_median_s']:.3f} s/material (isotropic {timing['select_iso_median_s']:.3f}, anisotropic "
        f"{timing['select_aniso_median_s']:.3f}) vs reconstruct {timing['reconstruct_median_s']:.3f} s; first calls "
        f"{timing['select_first_s']:.1f} s / {timing['reconstruct_first_s']:.1f} s"
    )

    log("the prior in the automatic choice (default prior):")
    prior_part = _selection_prior.run(names, meas_all, ref, log)
    out = {
        "prior": prior_part,
        "machine": machine(),
        "quick": quick,
        "noise_levels": list(noise),
        "tol": select.TOL,
        "level": select.LEVEL if hasattr(select, "LEVEL") else None,
        "min_effect": select.MIN_EFFECT,
        "merl": {
            "materials": names,
            "fixed": fixed,
            "auto": {"de76": auto_de, "logerr": auto_le},
            "best_fixed": best,
            "best_fixed_isotropic": best_iso,
            "rows": merl_rows,
            "noise": merl_noise,
        },
        "analytic": {"rows": a_rows},
        "timing": timing,
        "seconds": time.time() - t_start,
    }
    out["confusion"] = confusion(out)
    suffix = "_quick" if quick else ""
    path = write_json(f"model_selection{suffix}.json", out)
    md = markdown(out) + _selection_prior.markdown(prior_part)
    (RESULTS / f"model_selection{suffix}.md").write_text(md)
    chart(out, RESULTS / f"model_selection{suffix}.png")
    log(md)
    log(f"wrote {path}")


if __name__ == "__main__":
    main()
