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
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
import abrdf_jax._pipeline as P
from abrdf_jax._kernels import KERNELS
from abrdf_jax._rbf import _blocks, _centre_stats, _system, fit_rbf, fit_rbf_info, resolve_degree
from abrdf_jax._slices import PROTOCOL_PAIRS
from abrdf_jax.materials import dense_table, get_material
from abrdf_jax.materials._analytic import GGX, Ward
from abrdf_jax.metrics import evaluate_batch

from ._common import RESULTS, machine, write_json

log = functools.partial(print, file=sys.stderr, flush=True)

METHODS = {
    "paper iso102": aj.Config(),
    "recommended iso102": aj.Config.recommended(),
    "paper aniso204": aj.Config(budget="aniso204"),  # eq. (2)-(4), rule filip2012
    "recommended aniso204": aj.Config.recommended("aniso204"),
}


# ---------------------------------------------------------------------------------------------
# helpers


@contextlib.contextmanager
def _unguarded():
    """Trace the pipeline with the plain solve (``fit_rbf(guard=False)``): benchmark only."""
    saved = P.fit_rbf
    P.fit_rbf = functools.partial(fit_rbf, guard=False)
    try:
        yield
    finally:
        P.fit_rbf = saved


@functools.lru_cache(maxsize=None)
def recon_fn(config: aj.Config, guard: bool = True):
    """``jit(vmap(reconstruct))`` over materials for one configuration, guard on or off."""

    def core(meas, params):
        if guard:
            return P._reconstruct_core(meas, config, params)
        with _unguarded():
            return P._reconstruct_core(meas, config, params)

    return jax.jit(jax.vmap(core, in_axes=(0, None)))


def params_for(config, dtype, width=None, reg=None, alpha_deg=15.0):
    p = aj.Params.default(config, alpha_deg=alpha_deg, dtype=dtype)
    w = p.widths if width is None else jnp.full(4, width, dtype)
    r = p.reg if reg is None else jnp.asarray(reg, dtype)
    return aj.Params(p.alpha, w, r)


def sample_stack(models, config, params):
    return aj.stack_measurements([aj.sample(m, config, params, as_measurements=True) for m in models])


def with_y(meas, y=None, count=None, t=None):
    return aj.Measurements(meas.t if t is None else jnp.asarray(t, meas.t.dtype),
                           meas.y if y is None else jnp.asarray(y, meas.y.dtype),
                           meas.count if count is None else jnp.asarray(count, meas.count.dtype),
                           meas.pairs, meas.has_axial)


def de76(rec, ref):
    """Per-material ΔE76; NaN where the reconstruction is not finite."""
    rec, ref = np.asarray(rec, np.float64), np.asarray(ref, np.float64)
    finite = np.all(np.isfinite(rec.reshape(len(rec), -1)), axis=1)
    out = np.full(len(rec), np.nan)
    if finite.any():
        out[finite] = np.asarray(evaluate_batch(jnp.asarray(rec[finite], jnp.float32),
                                                jnp.asarray(ref[finite], jnp.float32))["de76"])
    return out


def nonfinite(rec) -> int:
    return int(np.sum(~np.isfinite(np.asarray(rec))))


def rbf_system(config, dtype, width, reg):
    """Centres of ``config``'s RBF and a function returning its guard diagnostics."""
    xc = P.pair_coordinates(*P.centre_vectors(config.pairs, dtype), config.parameterization)
    return xc


@functools.lru_cache(maxsize=None)
def _info_fn(kernel, degree, dtype, guard):
    def f(xc, widths, reg):
        zeros = jnp.zeros((xc.shape[0], 1), xc.dtype)
        return fit_rbf_info(xc, zeros, widths, kernel, reg, degree, guard=guard)[1]

    return jax.jit(f)


def solve_diag(config, dtype, width, reg, guard):
    xc = rbf_system(config, dtype, width, reg)
    info = _info_fn(config.kernel, config.degree, np.dtype(dtype).name, guard)(
        xc, jnp.full(4, width, dtype), jnp.asarray(reg, dtype))
    return {k: float(v) if k in ("reg", "cond") else int(v) for k, v in
            (("reg", info.reg), ("cond", info.cond), ("ok", info.ok), ("retries", info.retries))}


def exact_cond(config, width, reg):
    """Exact 1-norm condition number of the float64 system (numpy), to check the estimator."""
    xc = rbf_system(config, jnp.float64, width, reg)
    degree = resolve_degree(config.kernel, config.degree)
    shift, scale = _centre_stats(xc)
    k, p, _ = _blocks(xc, jnp.full(4, width, jnp.float64), config.kernel, degree, shift, scale)
    a = np.asarray(_system(k, p, jnp.asarray(reg, jnp.float64)))
    with np.errstate(all="ignore"):
        try:
            return float(np.linalg.cond(a, 1))
        except np.linalg.LinAlgError:
            return math.inf


def materials_iso(data_dir, count):
    """Isotropic materials with references: analytic ones plus MERL/Nielsen test networks."""
    names = ["lambert-clay", "ggx-plastic"]
    models = [get_material(n) for n in names]
    if count:
        try:
            from abrdf_jax.materials import load_tables81

            t = load_tables81(data_dir)
            test = [str(n) for n, s in zip(t["names"], t["split"]) if s == "test"]
            pick = test[:: max(1, len(test) // count)][:count]
            for n in pick:
                models.append(get_material("nbrdf:" + n, data_dir))
                names.append("nbrdf:" + n)
        except Exception as exc:  # no shared data: analytic materials only
            log(f"MERL networks unavailable ({exc}); analytic materials only")
    refs = np.stack([dense_table(m, np.float64) for m in models])
    return names, models, refs


# ---------------------------------------------------------------------------------------------
# 1. RBF conditioning


def conditioning(quick, names, models, refs):
    widths = (0.05, 0.45, 3.0) if quick else (0.05, 0.15, 0.45, 1.0, 2.0, 5.0)
    regs = (0.0, 1e-3)
    models, refs = models[:4], refs[:4]
    kernels = ("gaussian", "thin_plate_spline", "multiquadric") if quick else KERNELS
    rows = []
    for kernel in kernels:
        cfg = aj.Config(kernel=kernel)
        tables = {}
        for dtype in (jnp.float32, jnp.float64):
            dname = np.dtype(dtype).name
            meas = sample_stack(models, cfg, params_for(cfg, dtype))
            for w in widths:
                for reg in regs:
                    p = params_for(cfg, dtype, w, reg)
                    row = dict(kernel=kernel, dtype=dname, width=w, reg=reg)
                    bare = solve_diag(cfg, dtype, w, reg, guard=False)
                    guarded = solve_diag(cfg, dtype, w, reg, guard=True)
                    row.update(cond=bare["cond"], singular=not bare["ok"], guard_reg=guarded["reg"],
                               guard_retries=guarded["retries"], guard_ok=bool(guarded["ok"]),
                               guard_cond=guarded["cond"])
                    for tag, guard in (("guard", True), ("bare", False)):
                        if not guard and guarded["retries"] == 0:  # the guard kept λ: same solve
                            for key in ("nonfinite", "de76", "max"):
                                row[f"{key}_bare"] = row[f"{key}_guard"]
                            continue
                        rec = np.asarray(recon_fn(cfg, guard)(meas, p))
                        row[f"nonfinite_{tag}"] = nonfinite(rec)
                        row[f"de76_{tag}"] = float(np.nanmean(de76(rec, refs))) if np.isfinite(rec).any() else math.nan
                        row[f"max_{tag}"] = float(np.nanmax(np.where(np.isfinite(rec), np.abs(rec), np.nan))) if np.isfinite(rec).any() else math.nan
                        if guard:
                            tables[(dname, w, reg)] = rec
                    if dname == "float64" and reg == 0.0:
                        row["cond_exact"] = exact_cond(cfg, w, reg)
                    rows.append(row)
            log(f"conditioning {kernel} {dname} done")
        for row in rows:
            if row["kernel"] == kernel:
                t32, t64 = tables[("float32", row["width"], row["reg"])], tables[("float64", row["width"], row["reg"])]
                scale = np.max(np.abs(t64)) if np.isfinite(t64).all() else math.nan
                row["f32_vs_f64"] = float(np.max(np.abs(t32 - t64)) / scale) if np.isfinite(t32).all() and scale > 0 else math.nan
    return rows


def breaks(rows):
    """Per kernel and dtype: where the plain solve breaks, and what the guard does there."""
    out = []
    for kernel in dict.fromkeys(r["kernel"] for r in rows):
        for dname in ("float32", "float64"):
            rs = [r for r in rows if r["kernel"] == kernel and r["dtype"] == dname]
            if not rs:
                continue
            best = np.nanmin([r["de76_guard"] for r in rs])
            sing = [r for r in rs if r["singular"]]
            nan = [r for r in rs if r["nonfinite_bare"]]
            blow = [r for r in rs if not (r["de76_bare"] <= 2 * best)]  # NaN counts as blow-up
            f32 = [r for r in rs if r.get("f32_vs_f64", 0) > 1e-2]
            fmt = lambda lst: ", ".join(f"w={r['width']:.3g}/λ={r['reg']:g}" for r in lst) or "none"  # noqa: E731
            out.append(dict(
                kernel=kernel, dtype=dname, best_de76=float(best),
                singular=fmt(sing), nan_bare=fmt(nan), blowup_bare=fmt(blow),
                blowup_guard=fmt([r for r in rs if not (r["de76_guard"] <= 2 * best)]),
                nonfinite_guard=sum(r["nonfinite_guard"] for r in rs),
                retries=sum(r["guard_retries"] for r in rs), guard_not_ok=sum(not r["guard_ok"] for r in rs),
                f32_ne_f64=fmt(f32) if dname == "float32" else "",
                max_cond=float(np.nanmax([r["cond"] for r in rs])),
            ))
    return out


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
            t[b, s, :len(idx)], y[b, s, :len(idx)] = tt, yy
            c[b, s] = len(idx)
    return with_y(meas, y, c, t)


def run_method(name, meas, params, refs=None):
    rec = np.asarray(recon_fn(METHODS[name])(meas, params))
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
        refs = iso_refs if cfg.budget == "iso102" else np.concatenate([iso_refs[:2], dense_table(aniso_mat, np.float64)[None]])
        base = sample_stack(models, cfg, p)
        y = np.asarray(base.y)
        cnt = np.asarray(base.count)
        valid = np.arange(y.shape[2])[None, None, :] < cnt[..., None]
        cases = []

        def add(case, rec, err=None, note=""):
            entry = dict(method=name, case=case, nonfinite=nonfinite(rec),
                         min=float(np.nanmin(rec)) if np.isfinite(rec).any() else math.nan,
                         max=float(np.nanmax(rec)) if np.isfinite(rec).any() else math.nan, note=note)
            if err is not None:
                entry["error"] = float(np.nanmean(err)) if np.isfinite(err).any() else math.nan
            cases.append(entry)

        rec, e = run_method(name, base, p, refs)
        add("as measured (reference)", rec, e, "ΔE76")
        clean = e
        rec, _ = run_method(name, with_y(base, np.zeros_like(y)), p)
        add("all-zero material", rec, np.abs(rec).max(axis=(1, 2, 3)), "max |out|")
        rec, _ = run_method(name, with_y(base, np.where(valid[..., None], 0.3, 0.0)), p)
        add("constant 0.3", rec, np.abs(rec - 0.3).max(axis=(1, 2, 3)) / 0.3, "max relative deviation")
        # chrome: one material in a batch of one
        cm = chrome()
        cref = dense_table(cm, np.float64)[None]
        cmeas = sample_stack([cm], cfg, p)
        cy = np.asarray(cmeas.y)
        rec, e = run_method(name, cmeas, p, cref)
        ratio = float(np.max(cref) / np.median(cref))
        add("chrome-like peak", rec, e, f"ΔE76; dense max/median {ratio:.3g}, samples max/median "
            f"{float(np.max(cy) / np.median(cy[cy > 0])):.3g}")
        neg = y.copy()
        mask = valid & (rng.random(valid.shape) < 0.05)
        neg[mask] = -0.01 * np.mean(y[valid])
        rec, e = run_method(name, with_y(base, neg), p, refs)
        add("5% of samples negative", rec, e, "ΔE76 (output clamped at 0)")
        bad = y.copy()
        bad[:, 1, 3, 0] = np.nan
        rec, _ = run_method(name, with_y(base, bad), p)
        add("one NaN sample", rec, None, "non-finite values summed over the batch; the CSV reader and check_finite refuse it")
        # duplicated samples through the Samples path (group_slices averages repeats)
        one = aj.Measurements(base.t[0], base.y[0], base.count[0], base.pairs, base.has_axial)
        smp = one.to_samples().to_numpy()
        dup = aj.Samples(*(np.concatenate([a, a]) for a in (smp.theta_i, smp.phi_i, smp.theta_v, smp.phi_v)),
                         np.concatenate([smp.rgb, smp.rgb * 1.02]))
        rec = np.asarray(aj.reconstruct(dup, cfg, p))[None]
        add("every sample twice (values 2% apart)", rec, de76(rec, refs[:1]), "ΔE76, first material")
        near = aj.Samples(*(np.concatenate([a, a + (0.01 if k == 1 else 0.0)]) for k, a in
                            enumerate((smp.theta_i, smp.phi_i, smp.theta_v, smp.phi_v))),
                          np.concatenate([smp.rgb, smp.rgb * 1.05]))
        rec = np.asarray(aj.reconstruct(near, cfg, p))[None]
        add("samples repeated 0.01° apart (values 5% apart)", rec, de76(rec, refs[:1]), "ΔE76, first material")
        # missing slices
        for s_idx, what in ((0, "axial slice of pair 30/30 missing"), (1, "diagonal slice of pair 30/30 missing")):
            if cfg.budget == "iso102" and s_idx == 0:
                continue
            c2 = cnt.copy()
            c2[:, s_idx] = 0
            rec, e = run_method(name, with_y(base, count=c2), p, refs)
            add(what, rec, e, "ΔE76")
        # a missing elevation pair: the configuration without (75, 75)
        cfg3 = aj.Config(**{**{f: getattr(cfg, f) for f in ("budget", "rule", "kernel", "degree", "value_space")},
                            "pairs": PROTOCOL_PAIRS[:3]})
        m3 = sample_stack(models, cfg3, p)
        rec = np.asarray(recon_fn(cfg3)(m3, p))
        add("elevation pair 75/75 missing", rec, de76(rec, refs), "ΔE76")
        # α at the limits
        for a in (0.0, 0.01, 89.99, 90.0):
            pa = params_for(cfg, dt, alpha_deg=a)
            rec = np.asarray(recon_fn(cfg)(sample_stack(models, cfg, pa), pa))
            add(f"alpha = {a:g} deg", rec, de76(rec, refs), "ΔE76")
        out["cases"].extend(cases)
        out["curves"].setdefault("clean", {})[name] = float(np.nanmean(clean))
        # few samples per slice
        keeps = (12, 4, 2) if quick else (24, 12, 6, 4, 3, 2)
        out["curves"].setdefault("few_samples", {"x": list(keeps)})[name] = [
            float(np.nanmean(run_method(name, _few(base, k), p, refs)[1])) for k in keeps]
        # noise: multiplicative Gaussian noise on every sample
        sigmas = (0.0, 0.03, 0.3) if quick else (0.0, 0.01, 0.03, 0.1, 0.3)
        seeds = 1 if quick else 2
        curve = []
        for sig in sigmas:
            errs = []
            for _ in range(seeds):
                noisy = y * (1 + sig * rng.standard_normal(y.shape))
                errs.append(np.nanmean(run_method(name, with_y(base, np.where(valid[..., None], noisy, 0)), p, refs)[1]))
            curve.append(float(np.mean(errs)))
        out["curves"].setdefault("noise", {"x": list(sigmas)})[name] = curve
        log(f"data edges {name} done")
    return out


# ---------------------------------------------------------------------------------------------
# 3. method failures: anisotropy (isotropic shortcut, axis rotation) and the eq. (4) remap


def ward(ratio, rotation_deg=0.0):
    a0 = 0.15
    return Ward(diffuse=[0.04, 0.04, 0.045], specular=[0.30, 0.30, 0.32], alpha_x=a0 / math.sqrt(ratio),
                alpha_y=a0 * math.sqrt(ratio), rotation=math.radians(rotation_deg))


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
        out["strength"][name] = [float(v) for v in run_method(name, sample_stack(mats_s, cfg, p), p, ref_s)[1]]
        out["rotation"][name] = [float(v) for v in run_method(name, sample_stack(mats_r, cfg, p), p, ref_r)[1]]
    log("anisotropy done")
    return out


def eq4(quick):
    """Rules of the toroidal subspace as a sharper anisotropic peak dominates one slice's range."""
    dt = jnp.float32
    alphas = (0.3, 0.1, 0.03) if quick else (0.4, 0.2, 0.1, 0.05, 0.03, 0.02)
    mats = [GGX(diffuse=[0.08, 0.1, 0.12], specular_f0=0.9, alpha_x=a, alpha_y=3 * a) for a in alphas]
    refs = np.stack([dense_table(m, np.float64) for m in mats])
    out = {"x_alpha": list(alphas)}
    for rule in ("filip2012", "average", "crossing", "log"):
        cfg = aj.Config(budget="aniso204", rule=rule, kernel="thin_plate_spline", value_space="log")
        p = params_for(cfg, dt)
        meas = sample_stack(mats, cfg, p)
        if rule == "filip2012":
            y, c = np.asarray(meas.y), np.asarray(meas.count)
            valid = np.arange(y.shape[2])[None, None, :] < c[..., None]
            yy = np.where(valid[..., None], y, np.nan)[..., 1]
            # dynamic range of each slice (max/min, green), and the share of the largest slice
            out["range_diag"] = [float(np.nanmax(yy[b, 1]) / np.nanmin(yy[b, 1])) for b in range(len(mats))]
            out["range_axial"] = [float(np.nanmax(yy[b, 0]) / np.nanmin(yy[b, 0])) for b in range(len(mats))]
        out[rule] = [float(v) for v in de76(recon_fn(cfg)(meas, p), refs)]
    cfg = aj.Config.recommended("iso102")
    p = params_for(cfg, dt)
    out["iso102 (diagonal)"] = [float(v) for v in de76(recon_fn(cfg)(sample_stack(mats, cfg, p), p), refs)]
    log("eq4 done")
    return out


# ---------------------------------------------------------------------------------------------
# output


def charts(payload, suffix):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = payload["conditioning"]
    kernels = list(dict.fromkeys(r["kernel"] for r in rows))
    paths = []
    # condition vs width (λ = 0, plain solve), both dtypes
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, dname in zip(axes, ("float32", "float64")):
        for k in kernels:
            rs = [r for r in rows if r["kernel"] == k and r["dtype"] == dname and r["reg"] == 0.0]
            ax.loglog([r["width"] for r in rs], [r["cond"] for r in rs], "o-", label=k, ms=3)
        ax.axhline(1 / np.finfo(dname).eps, color="k", ls="--", lw=1)
        ax.text(ax.get_xlim()[0], 1 / np.finfo(dname).eps, " 1/ε: guard threshold", va="bottom", fontsize=8)
        ax.set_title(f"estimated condition, λ = 0, {dname}")
        ax.set_xlabel("kernel width ℓ (radians of the onion coordinates)")
    axes[0].set_ylabel("κ₁ (Hager estimate)")
    axes[1].legend(fontsize=7)
    paths.append(_save(fig, f"stability_condition{suffix}.png"))
    # error vs width: guard off / on, f32 and f64, λ = 0
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, dname in zip(axes, ("float32", "float64")):
        for i, k in enumerate(kernels):
            rs = [r for r in rows if r["kernel"] == k and r["dtype"] == dname and r["reg"] == 0.0]
            col = f"C{i}"
            ax.semilogx([r["width"] for r in rs], [r["de76_bare"] for r in rs], "x--", color=col, ms=4)
            ax.semilogx([r["width"] for r in rs], [r["de76_guard"] for r in rs], "o-", color=col, ms=3, label=k)
        ax.set_yscale("log")
        ax.set_title(f"ΔE76 vs width, λ = 0, {dname}\n(solid: guard on; dashed: off; gaps: NaN)", fontsize=10)
        ax.set_xlabel("kernel width ℓ")
    axes[0].set_ylabel("mean ΔE76")
    axes[1].legend(fontsize=7)
    paths.append(_save(fig, f"stability_width{suffix}.png"))
    curves = payload["data_edges"]["curves"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name in METHODS:
        axes[0].plot(curves["noise"]["x"], curves["noise"][name], "o-", label=name, ms=3)
        axes[1].plot(curves["few_samples"]["x"], curves["few_samples"][name], "o-", label=name, ms=3)
    axes[0].set_xlabel("multiplicative noise σ")
    axes[0].set_title("ΔE76 vs measurement noise")
    axes[1].set_xlabel("samples kept per slice (of 24-26)")
    axes[1].set_title("ΔE76 vs samples per slice")
    axes[1].invert_xaxis()
    for ax in axes:
        ax.set_ylabel("mean ΔE76")
    axes[0].legend(fontsize=7)
    paths.append(_save(fig, f"stability_noise{suffix}.png"))
    an = payload["anisotropy"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name in METHODS:
        axes[0].plot(an["strength"]["x"], an["strength"][name], "o-", label=name, ms=3)
        axes[1].plot(an["rotation"]["x"], an["rotation"][name], "o-", label=name, ms=3)
    axes[0].set_xlabel("anisotropy α_y / α_x (Ward, axis along x)")
    axes[0].set_title("ΔE76 vs anisotropy strength")
    axes[1].set_xlabel("axis rotation (degrees; α_y/α_x = 5)")
    axes[1].set_title("ΔE76 vs anisotropy axis rotation")
    for ax in axes:
        ax.set_ylabel("ΔE76")
    axes[0].legend(fontsize=7)
    paths.append(_save(fig, f"stability_anisotropy{suffix}.png"))
    e4 = payload["eq4"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for rule in ("filip2012", "average", "crossing", "log", "iso102 (diagonal)"):
        ax.semilogx(e4["range_diag"], e4[rule], "o-", label=rule, ms=3)
    ax.set_xlabel("dynamic range of the diagonal slice at 30/30 (max/min)")
    ax.set_ylabel("ΔE76")
    ax.set_title("subspace rules vs a dominating specular slice (aniso204)")
    ax.legend(fontsize=7)
    paths.append(_save(fig, f"stability_eq4{suffix}.png"))
    return paths


def _save(fig, name):
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = RESULTS / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path.relative_to(RESULTS.parent.parent))


def g(v, f=".3g"):
    return "NaN" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, f)


def markdown(payload) -> str:
    out = [f"# Stability benchmark ({'quick' if payload['quick'] else 'full'} run)", "",
           f"`python -m benchmarks.stability{' --quick' if payload['quick'] else ''}`, "
           f"{payload['seconds']:.0f} s, {payload['machine']['date']}, {payload['machine']['jax_devices']}, "
           f"materials: {', '.join(payload['materials'])}", "",
           "## RBF conditioning: where the plain solve breaks (iso102 system, 1296 centres)", "",
           "| kernel | dtype | max κ₁ | singular (κ ≥ 1/ε) | NaN, guard off | ΔE > 2× best, guard off | "
           "ΔE > 2× best, guard on | best ΔE | guard retries / not ok | f32 ≠ f64 (>1%) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for b in payload["breaks"]:
        out.append(f"| {b['kernel']} | {b['dtype']} | {g(b['max_cond'])} | {b['singular']} | {b['nan_bare']} | "
                   f"{b['blowup_bare']} | {b['blowup_guard']} | {g(b['best_de76'], '.2f')} | "
                   f"{b['retries']} / {b['guard_not_ok']} | {b['f32_ne_f64']} |")
    est = [(r["cond"], r["cond_exact"]) for r in payload["conditioning"]
           if "cond_exact" in r and np.isfinite(r["cond_exact"]) and r["cond_exact"] < 1e15]
    if est:
        ratio = np.array([e / c for c, e in est])
        out += ["", f"Hager estimate vs exact κ₁ (float64, κ < 1e15, {len(est)} systems): exact/estimate "
                f"median {np.median(ratio):.3g}, max {np.max(ratio):.3g}."]
    out += ["", "## Data edges (float32, package defaults of each method)", "",
            "Materials: iso102 columns the isotropic set above; aniso204 columns lambert-clay, ggx-plastic "
            "and ward-brushed-steel. Errors are means over the batch.", "",
            "| case | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    cases = payload["data_edges"]["cases"]
    for case in dict.fromkeys(c["case"] for c in cases):
        cells = []
        for name in METHODS:
            c = next((c for c in cases if c["case"] == case and c["method"] == name), None)
            if c is None:
                cells.append("n/a")
            elif c["nonfinite"]:
                cells.append(f"**{c['nonfinite']} non-finite**")
            else:
                cells.append(g(c.get("error")) + (f" (min {g(c['min'])})" if c["min"] < 0 else ""))
        note = next(c["note"] for c in cases if c["case"] == case)
        out.append(f"| {case} ({note}) | " + " | ".join(cells) + " |")
    curves = payload["data_edges"]["curves"]
    for key, label in (("noise", "noise σ"), ("few_samples", "samples per slice")):
        xs = curves[key]["x"]
        out += ["", f"ΔE76 vs {label}:", "", "| method | " + " | ".join(g(x) for x in xs) + " |",
                "|---|" + "---|" * len(xs)]
        out += [f"| {n} | " + " | ".join(g(v, ".2f") for v in curves[key][n]) + " |" for n in METHODS]
    an = payload["anisotropy"]
    for key, label in (("strength", "anisotropy α_y/α_x"), ("rotation", "axis rotation (deg)")):
        xs = an[key]["x"]
        out += ["", f"ΔE76 vs {label} (Ward):", "", "| method | " + " | ".join(g(x) for x in xs) + " |",
                "|---|" + "---|" * len(xs)]
        out += [f"| {n} | " + " | ".join(g(v, ".2f") for v in an[key][n]) + " |" for n in METHODS]
    e4 = payload["eq4"]
    out += ["", "Eq. (4) and the other subspace rules (aniso204, recommended RBF), GGX α_x = a, α_y = 3a:", "",
            "| a | diagonal-slice range | axial-slice range | " + " | ".join(("filip2012", "average", "crossing", "log", "iso102 (diagonal)")) + " |",
            "|---|---|---|---|---|---|---|---|"]
    for i, a in enumerate(e4["x_alpha"]):
        out.append(f"| {a:g} | {g(e4['range_diag'][i])} | {g(e4['range_axial'][i])} | " + " | ".join(
            g(e4[r][i], ".2f") for r in ("filip2012", "average", "crossing", "log", "iso102 (diagonal)")) + " |")
    out += ["", "Charts: " + ", ".join(f"`{p}`" for p in payload["charts"]), ""]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few points per sweep (smoke run)")
    ap.add_argument("--data-dir", default=None, help="shared data folder (default: the package's lookup)")
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # float64 is needed for the f32/f64 comparison
    t0 = time.time()
    rng = np.random.default_rng(0)
    names, models, refs = materials_iso(args.data_dir, 2 if args.quick else 4)
    cond_rows = conditioning(args.quick, names, models, refs)
    payload = dict(machine=machine(), quick=args.quick, materials=names, conditioning=cond_rows,
                   breaks=breaks(cond_rows))
    payload["data_edges"] = data_edges(args.quick, models, refs, rng)
    payload["anisotropy"] = anisotropy(args.quick)
    payload["eq4"] = eq4(args.quick)
    payload["seconds"] = time.time() - t0
    suffix = "_quick" if args.quick else ""
    payload["charts"] = charts(payload, suffix)
    write_json(f"stability{suffix}.json", payload)
    (RESULTS / f"stability{suffix}.md").write_text(markdown(payload))
    log(f"wrote benchmarks/results/stability{suffix}.json, .md and {len(payload['charts'])} charts "
        f"in {payload['seconds']:.0f} s")


if __name__ == "__main__":
    main()
