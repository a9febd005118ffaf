"""The prior-only model in the automatic choice (part of ``python -m benchmarks.model_selection``).

``select_models(..., prior=default_prior())`` (``abrdf-jax reconstruct --model auto --prior``):
the RBF candidates and the default prior by held-out error with the 5 % rule, the prior ranked
above every RBF model (an isotropic material's bivariate model has no held-out error: with a
prior the RBF's ``iso`` takes its place). Reported on the MERL test split (aniso204 samples, noise-free) and on the
package's built-in analytic materials (``abrdf-jax materials``; the anisotropic and procedural
ones: ggx-aniso-metal, ward-brushed-steel, rough-fabric, rough-grooves among them): each
material's choice with and without the prior, and the mean dense ΔE76 of the choice beside every
fixed model (the RBF candidates, the bivariate model, the prior alone) and the best of them.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax import prior as P
from abrdf_jax import select
from abrdf_jax.materials import dense_table, get_material, is_anisotropic, material_names
from abrdf_jax.select import CANDIDATES, DEFAULT_ANISO

from ._common import metrics_of

PRIOR = "prior"
#: The learned candidates of ``select_models(..., prior=)``: the prior alone and the fused model.
LEARNED = (PRIOR, "fused")


def _dense(stack, ref, prior) -> dict:
    """Dense ΔE76 ``{model: (B,)}`` of every default candidate, the prior alone and the fused
    model (each learned one on the slices its choice reads: all (aniso204) or the diagonal ones
    (iso102))."""
    out = {}
    for n in DEFAULT_ANISO:
        cfg = CANDIDATES[n].config()
        rec = aj.reconstruct_batch(stack, cfg, aj.Params.default(cfg, dtype=jnp.float32))
        out[n] = metrics_of(rec, ref)["de76"]
    out["bivariate"] = bivariate_metrics(stack, ref)["de76"]
    diag = np.asarray(stack.count).copy()
    diag[:, 0::2] = 0
    iso = stack.replace(count=jnp.asarray(diag, stack.count.dtype))
    hyper, reference = P.learned_hyper(prior, "fused", prior.dtype)
    for budget, m in (("aniso204", stack), ("iso102", iso)):
        out[f"{PRIOR}/{budget}"] = metrics_of(P.reconstruct_prior(m, prior), ref)["de76"]
        fused = P.reconstruct_fused(m, prior, hyper, reference=reference)
        out[f"fused/{budget}"] = metrics_of(fused, ref)["de76"]
    return out


def bivariate_metrics(stack, ref, log=None) -> dict:
    """``{"de76": (B,), "logerr": (B,)}`` of the bivariate model (``--model auto``'s choice
    wherever an isotropic model wins) on every slice of each member of ``stack``, one numpy fit
    per material."""
    t0 = time.perf_counter()
    members = [jax.tree_util.tree_map(lambda x, i=i: x[i], stack) for i in range(len(ref))]
    rec = jnp.stack([aj.reconstruct_bivariate(m.to_samples()) for m in members])
    m = metrics_of(rec, ref)
    if log is not None:
        log(
            f"  {'bivariate':15s} dense ΔE76 {np.mean(m['de76']):6.2f}  LogErr "
            f"{np.mean(m['logerr']):.3f}  ({time.perf_counter() - t0:.0f} s)"
        )
    return {"de76": m["de76"], "logerr": m["logerr"]}


def _rows(names, meas, dense, with_prior, without) -> list[dict]:
    rows = []
    for i, n in enumerate(names):
        s, s0 = with_prior[i], without[i]
        key = s.name if s.name not in LEARNED else f"{s.name}/{s.config.budget}"
        rows.append(
            {
                "material": n,
                "choice": s.name,
                "choice_budget": s.config.budget,
                "choice_without_prior": s0.name,
                "held_out": s.errors,
                "de76_choice": float(dense[key][i]),
                "de76_choice_without_prior": float(dense[s0.name][i]),
                "de76": {m: float(v[i]) for m, v in dense.items()},
            }
        )
    return rows


def _summary(rows) -> dict:
    models = list(rows[0]["de76"])
    fixed = {m: float(np.mean([r["de76"][m] for r in rows])) for m in models}
    best = min(fixed, key=fixed.get)
    return {
        "n": len(rows),
        "auto_with_prior": float(np.mean([r["de76_choice"] for r in rows])),
        "auto_without_prior": float(np.mean([r["de76_choice_without_prior"] for r in rows])),
        "fixed": fixed,
        "best_fixed": best,
        "prior_chosen": sum(r["choice"] == PRIOR for r in rows),
        "fused_chosen": sum(r["choice"] == "fused" for r in rows),
        # per material: the choice against the better of the RBF models' choice and the best RBF
        "worse_than_rbf_choice_3pct": [
            r["material"] for r in rows if r["de76_choice"] > 1.03 * r["de76_choice_without_prior"]
        ],
    }


def run(merl_names, merl_stack, merl_ref, log=print) -> dict:
    """The section's results: ``{"merl": ..., "builtin": ..., "seconds": ...}``."""
    t0 = time.time()
    prior = P.default_prior()
    cfg = aj.Config.recommended("aniso204")
    p = aj.Params.default(cfg, dtype=jnp.float32)
    b_names = list(material_names())
    b_meas = [aj.sample(get_material(n), cfg, p, as_measurements=True) for n in b_names]
    b_stack = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *b_meas)
    b_ref = jnp.stack([jnp.asarray(dense_table(get_material(n))) for n in b_names])
    out = {"prior": {"n_components": prior.n_components, "lam": float(prior.lam)}}
    for key, names, stack, ref in (
        ("merl", merl_names, merl_stack, merl_ref),
        ("builtin", b_names, b_stack, b_ref),
    ):
        meas = [jax.tree_util.tree_map(lambda x, i=i: x[i], stack) for i in range(len(names))]
        with_prior = select.select_models(meas, prior=prior)
        without = select.select_models(meas)
        rows = _rows(names, meas, _dense(stack, ref, prior), with_prior, without)
        if key == "builtin":
            for r in rows:
                r["anisotropic_or_procedural"] = bool(is_anisotropic(r["material"]))
        out[key] = {"rows": rows, **_summary(rows)}
        s = out[key]
        log(
            f"  auto with the prior, {key}: ΔE76 {s['auto_with_prior']:.3f} (without "
            f"{s['auto_without_prior']:.3f}; best fixed {s['best_fixed']} "
            f"{s['fixed'][s['best_fixed']]:.3f}); prior chosen for {s['prior_chosen']}/{s['n']}, "
            f"fused for {s['fused_chosen']}/{s['n']}"
        )
        for r in rows if key == "builtin" else ():
            log(
                f"    {r['material']:20s} -> {r['choice']:15s} ΔE76 {r['de76_choice']:.2f} "
                f"(without the prior: {r['choice_without_prior']} {r['de76_choice_without_prior']:.2f})"
            )
    out["seconds"] = time.time() - t0
    return out


def markdown(sec: dict) -> str:
    lines = [
        "",
        "Automatic choice with the default prior among the candidates (`--model auto --prior "
        f"default`; K = {sec['prior']['n_components']}, λ = {sec['prior']['lam']:g}), mean dense "
        "ΔE76:",
        "",
        "| set | auto + prior | auto (no prior) | best fixed model | prior alone (all slices) "
        "| fused (all slices) | prior chosen | fused chosen |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key, label in (("merl", "MERL test"), ("builtin", "built-in analytic")):
        s = sec[key]
        lines.append(
            f"| {label} ({s['n']}) | {s['auto_with_prior']:.3f} | {s['auto_without_prior']:.3f} | "
            f"{s['best_fixed']} {s['fixed'][s['best_fixed']]:.3f} | "
            f"{s['fixed'][PRIOR + '/aniso204']:.3f} | {s['fixed']['fused/aniso204']:.3f} | "
            f"{s['prior_chosen']} | {s['fused_chosen']} |"
        )
    lines += ["", "| built-in material | choice (+ prior) | ΔE76 | choice (no prior) | ΔE76 |"]
    lines.append("|---|---|---|---|---|")
    for r in sec["builtin"]["rows"]:
        mark = " (aniso/procedural)" if r["anisotropic_or_procedural"] else ""
        lines.append(
            f"| {r['material']}{mark} | {r['choice']} | {r['de76_choice']:.2f} | "
            f"{r['choice_without_prior']} | {r['de76_choice_without_prior']:.2f} |"
        )
    return "\n".join(lines) + "\n"
