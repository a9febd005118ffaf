"""Parts 2 and 3 of the stability benchmark (:mod:`benchmarks.stability`): data edges through the four
methods, and method failures (anisotropy strength and axis rotation; the eq. (4) min–max remap).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import GGX, Ward, dense_table, get_material

from ._stability_common import METHODS, de76, log, nonfinite, params_for, reconstruct, sample_stack


# ---------------------------------------------------------------------------------------------
# 2. data edges


def _few(meas, keep):
    """Keep ``keep`` roughly evenly spread samples of every slice (same padded shape)."""
    t, y, c = np.array(meas.t), np.array(meas.y), np.array(meas.count)
    for b in range(t.shape[0]):
        for s in range(t.shape[1]):
            n = int(c[b, s])
            if n == 0:
                continue
            idx = np.unique(np.round(np.linspace(0, n, min(keep, n), endpoint=False)).astype(int))
            tt, yy = t[b, s, idx], y[b, s, idx]
            t[b, s] = 0.0
            y[b, s] = 0.0
            t[b, s, : len(idx)], y[b, s, : len(idx)] = tt, yy
            c[b, s] = len(idx)
    return with_y(meas, y, c, t)


def with_y(meas, y=None, count=None, t=None):
    """``meas`` with some of ``y``, ``count``, ``t`` replaced (in the measurement's dtypes)."""
    new = dict(t=t, y=y, count=count)
    return meas.replace(
        **{k: jnp.asarray(v, getattr(meas, k).dtype) for k, v in new.items() if v is not None}
    )


def run_method(name, meas, params, refs=None):
    rec = reconstruct(METHODS[name], meas, params)
    return rec, (de76(rec, refs) if refs is not None else None)


def chrome():
    # Mirror-like metal over a faint diffuse base: the peak is ~10^4 times the diffuse level.
    return GGX(diffuse=0.003, specular_f0=[0.95, 0.93, 0.88], alpha_x=0.03, alpha_y=0.03)


def data_edges(quick, iso_models, iso_refs, rng):
    dt = jnp.float32
    out = {"cases": [], "curves": {}}
    aniso_mat = get_material("ward-brushed-steel")
    for name, cfg in METHODS.items():
        p = params_for(cfg, dt)
        models = iso_models if cfg.budget == "iso102" else [*iso_models[:2], aniso_mat]
        refs = (
            iso_refs
            if cfg.budget == "iso102"
            else np.concatenate([iso_refs[:2], dense_table(aniso_mat, np.float64)[None]])
        )
        base = sample_stack(models, cfg, p)
        y = np.asarray(base.y)
        cnt = np.asarray(base.count)
        valid = np.asarray(base.mask)
        cases = []

        def add(case, rec, err=None, note=""):
            entry = dict(
                method=name,
                case=case,
                nonfinite=nonfinite(rec),
                min=float(np.nanmin(rec)) if np.isfinite(rec).any() else math.nan,
                max=float(np.nanmax(rec)) if np.isfinite(rec).any() else math.nan,
                note=note,
            )
            if err is not None:
                entry["error"] = float(np.nanmean(err)) if np.isfinite(err).any() else math.nan
            cases.append(entry)

        rec, e = run_method(name, base, p, refs)
        add("as measured (reference)", rec, e, "ΔE76")
        clean = e
        rec, _ = run_method(name, with_y(base, np.zeros_like(y)), p)
        add("all-zero material", rec, np.abs(rec).max(axis=(1, 2, 3)), "max |out|")
        rec, _ = run_method(name, with_y(base, np.where(valid[..., None], 0.3, 0.0)), p)
        add(
            "constant 0.3",
            rec,
            np.abs(rec - 0.3).max(axis=(1, 2, 3)) / 0.3,
            "max relative deviation",
        )
        # chrome: one material in a batch of one
        cm = chrome()
        cref = dense_table(cm, np.float64)[None]
        cmeas = sample_stack([cm], cfg, p)
        cy = np.asarray(cmeas.y)
        rec, e = run_method(name, cmeas, p, cref)
        ratio = float(np.max(cref) / np.median(cref))
        add(
            "chrome-like peak",
            rec,
            e,
            f"ΔE76; dense max/median {ratio:.3g}, samples max/median "
            f"{float(np.max(cy) / np.median(cy[cy > 0])):.3g}",
        )
        neg = y.copy()
        mask = valid & (rng.random(valid.shape) < 0.05)
        neg[mask] = -0.01 * np.mean(y[valid])
        rec, e = run_method(name, with_y(base, neg), p, refs)
        add("5% of samples negative", rec, e, "ΔE76 (output clamped at 0)")
        bad = y.copy()
        bad[:, 1, 3, 0] = np.nan
        rec, _ = run_method(name, with_y(base, bad), p)
        add(
            "one NaN sample",
            rec,
            None,
            "non-finite values summed over the batch; the CSV reader and check_finite refuse it",
        )
        # duplicated samples through the Samples path (group_slices averages repeats)
        one = jax.tree_util.tree_map(lambda x: x[0], base)
        smp = one.to_samples().to_numpy()
        dup = aj.Samples(
            *(np.concatenate([a, a]) for a in (smp.theta_i, smp.phi_i, smp.theta_v, smp.phi_v)),
            np.concatenate([smp.rgb, smp.rgb * 1.02]),
        )
        rec = np.asarray(aj.reconstruct(dup, cfg, p))[None]
        add(
            "every sample twice (values 2% apart)", rec, de76(rec, refs[:1]), "ΔE76, first material"
        )
        near = aj.Samples(
            *(
                np.concatenate([a, a + (0.01 if k == 1 else 0.0)])
                for k, a in enumerate((smp.theta_i, smp.phi_i, smp.theta_v, smp.phi_v))
            ),
            np.concatenate([smp.rgb, smp.rgb * 1.05]),
        )
        rec = np.asarray(aj.reconstruct(near, cfg, p))[None]
        add(
            "samples repeated 0.01° apart (values 5% apart)",
            rec,
            de76(rec, refs[:1]),
            "ΔE76, first material",
        )
        # missing slices
        for s_idx, what in (
            (0, "axial slice of pair 30/30 missing"),
            (1, "diagonal slice of pair 30/30 missing"),
        ):
            if cfg.budget == "iso102" and s_idx == 0:
                continue
            c2 = cnt.copy()
            c2[:, s_idx] = 0
            rec, e = run_method(name, with_y(base, count=c2), p, refs)
            add(what, rec, e, "ΔE76")
        # a missing elevation pair: the configuration without (75, 75)
        cfg3 = aj.Config(
            **{
                **{
                    f: getattr(cfg, f)
                    for f in ("budget", "rule", "kernel", "degree", "value_space")
                },
                "pairs": aj.PROTOCOL_PAIRS[:3],
            }
        )
        m3 = sample_stack(models, cfg3, p)
        rec = reconstruct(cfg3, m3, p)
        add("elevation pair 75/75 missing", rec, de76(rec, refs), "ΔE76")
        # α at the limits
        for a in (0.0, 0.01, 89.99, 90.0):
            pa = params_for(cfg, dt, alpha_deg=a)
            rec = reconstruct(cfg, sample_stack(models, cfg, pa), pa)
            add(f"alpha = {a:g} deg", rec, de76(rec, refs), "ΔE76")
        out["cases"].extend(cases)
        out["curves"].setdefault("clean", {})[name] = float(np.nanmean(clean))
        # few samples per slice
        keeps = (12, 4, 2) if quick else (24, 12, 6, 4, 3, 2)
        out["curves"].setdefault("few_samples", {"x": list(keeps)})[name] = [
            float(np.nanmean(run_method(name, _few(base, k), p, refs)[1])) for k in keeps
        ]
        # noise: multiplicative Gaussian noise on every sample
        sigmas = (0.0, 0.03, 0.3) if quick else (0.0, 0.01, 0.03, 0.1, 0.3)
        seeds = 1 if quick else 2
        curve = []
        for sig in sigmas:
            errs = []
            for _ in range(seeds):
                noisy = y * (1 + sig * rng.standard_normal(y.shape))
                errs.append(
                    np.nanmean(
                        run_method(
                            name, with_y(base, np.where(valid[..., None], noisy, 0)), p, refs
                        )[1]
                    )
                )
            curve.append(float(np.mean(errs)))
        out["curves"].setdefault("noise", {"x": list(sigmas)})[name] = curve
        log(f"data edges {name} done")
    return out


# ---------------------------------------------------------------------------------------------
# 3. method failures: anisotropy (isotropic shortcut, axis rotation) and the eq. (4) remap


def ward(ratio, rotation_deg=0.0):
    a0 = 0.15
    return Ward(
        diffuse=[0.04, 0.04, 0.045],
        specular=[0.30, 0.30, 0.32],
        alpha_x=a0 / math.sqrt(ratio),
        alpha_y=a0 * math.sqrt(ratio),
        rotation=math.radians(rotation_deg),
    )


def anisotropy(quick):
    dt = jnp.float32
    ratios = (1.0, 3.0, 8.0) if quick else (1.0, 1.5, 2.0, 3.0, 5.0, 8.0)
    rots = (0.0, 45.0, 90.0) if quick else (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0)
    mats_s = [ward(r) for r in ratios]
    mats_r = [ward(5.0, d) for d in rots]
    ref_s = np.stack([dense_table(m, np.float64) for m in mats_s])
    ref_r = np.stack([dense_table(m, np.float64) for m in mats_r])
    out = {"strength": {"x": list(ratios)}, "rotation": {"x": list(rots)}}
    for name, cfg in METHODS.items():
        p = params_for(cfg, dt)
        out["strength"][name] = [
            float(v) for v in run_method(name, sample_stack(mats_s, cfg, p), p, ref_s)[1]
        ]
        out["rotation"][name] = [
            float(v) for v in run_method(name, sample_stack(mats_r, cfg, p), p, ref_r)[1]
        ]
    log("anisotropy done")
    return out


def eq4(quick):
    """Rules of the toroidal subspace as a sharper anisotropic peak dominates one slice's range."""
    dt = jnp.float32
    alphas = (0.3, 0.1, 0.03) if quick else (0.4, 0.2, 0.1, 0.05, 0.03, 0.02)
    mats = [
        GGX(diffuse=[0.08, 0.1, 0.12], specular_f0=0.9, alpha_x=a, alpha_y=3 * a) for a in alphas
    ]
    refs = np.stack([dense_table(m, np.float64) for m in mats])
    out = {"x_alpha": list(alphas)}
    for rule in ("filip2012", "average", "crossing", "log"):
        cfg = aj.Config(budget="aniso204", rule=rule, kernel="thin_plate_spline", value_space="log")
        p = params_for(cfg, dt)
        meas = sample_stack(mats, cfg, p)
        if rule == "filip2012":
            y = np.asarray(meas.y)
            valid = np.asarray(meas.mask)
            yy = np.where(valid[..., None], y, np.nan)[..., 1]
            # dynamic range of each slice (max/min, green), and the share of the largest slice
            out["range_diag"] = [
                float(np.nanmax(yy[b, 1]) / np.nanmin(yy[b, 1])) for b in range(len(mats))
            ]
            out["range_axial"] = [
                float(np.nanmax(yy[b, 0]) / np.nanmin(yy[b, 0])) for b in range(len(mats))
            ]
        out[rule] = [float(v) for v in de76(reconstruct(cfg, meas, p), refs)]
    cfg = aj.Config.recommended("iso102")
    p = params_for(cfg, dt)
    out["iso102 (diagonal)"] = [
        float(v) for v in de76(reconstruct(cfg, sample_stack(mats, cfg, p), p), refs)
    ]
    log("eq4 done")
    return out
