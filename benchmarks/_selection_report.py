"""The report of ``python -m benchmarks.model_selection``: the confusion table, the markdown and
the chart, from the run's results (``out``)."""

from __future__ import annotations

import numpy as np

from abrdf_jax.select import BIVARIATE, CANDIDATES, DEFAULT_ANISO


def isotropic_model(name: str) -> bool:
    """An isotropic model (the bivariate one or an RBF candidate on the diagonal slices)."""
    return name == BIVARIATE or CANDIDATES[name].settings["budget"] == "iso102"


def confusion(out) -> dict:
    """Counts: truth (isotropic / anisotropic) x decision, per noise level; and 'materially better'."""
    rows = {}
    for s in out["noise_levels"]:
        key = str(s)
        mi = out["merl"]["noise"][key]
        an = [r for r in out["analytic"]["rows"] if r["noise"] == s]
        a_true = [r for r in an if not r["truly_isotropic"]]
        a_iso = [r for r in an if r["truly_isotropic"]]
        mat = [r for r in a_true if r["aniso_material"]]
        imm = [r for r in a_true if not r["aniso_material"]]
        rows[key] = {
            "merl_isotropic": [mi["isotropic"], mi["anisotropic"]],
            "analytic_isotropic": [
                sum(r["isotropic_test"] for r in a_iso),
                sum(not r["isotropic_test"] for r in a_iso),
            ],
            "analytic_anisotropic": [
                sum(r["isotropic_test"] for r in a_true),
                sum(not r["isotropic_test"] for r in a_true),
            ],
            "aniso_material": [
                sum(isotropic_model(r["choice"]) for r in mat),
                sum(not isotropic_model(r["choice"]) for r in mat),
            ],
            "aniso_immaterial": [
                sum(isotropic_model(r["choice"]) for r in imm),
                sum(not isotropic_model(r["choice"]) for r in imm),
            ],
        }
    return rows


def markdown(out) -> str:
    c = out["confusion"]
    lv = out["noise_levels"]
    head = "| truth | " + " | ".join(f"σ = {s:g}: iso / aniso" for s in lv) + " |"
    lines = [
        "Isotropy decision (test alone) and final model budget (automatic choice):",
        "",
        head,
        "|---|" + "---|" * len(lv),
    ]
    labels = (
        ("merl_isotropic", "isotropic: MERL test (test decision)"),
        ("analytic_isotropic", "isotropic: analytic, ratio 1 (test decision)"),
        ("analytic_anisotropic", "anisotropic: analytic (test decision)"),
        (
            "aniso_material",
            "anisotropic, aniso model ≥5% better than bivariate (final model iso / aniso)",
        ),
        (
            "aniso_immaterial",
            "anisotropic, aniso model <5% better than bivariate (final model iso / aniso)",
        ),
    )
    for key, label in labels:
        lines.append(
            f"| {label} | "
            + " | ".join(f"{c[str(s)][key][0]} / {c[str(s)][key][1]}" for s in lv)
            + " |"
        )
    m = out["merl"]
    lines += [
        "",
        f"MERL test ({len(m['materials'])} materials, aniso204 samples, noise-free): automatic choice mean ΔE76 "
        f"{m['auto']['de76']:.3f} (LogErr {m['auto']['logerr']:.4f}); best fixed model {m['best_fixed']} "
        f"{m['fixed'][m['best_fixed']]['de76']:.3f} ({100 * (m['auto']['de76'] / m['fixed'][m['best_fixed']]['de76'] - 1):+.1f}%); "
        f"best fixed isotropic model {m['best_fixed_isotropic']} {m['fixed'][m['best_fixed_isotropic']]['de76']:.3f} "
        f"({100 * (m['auto']['de76'] / m['fixed'][m['best_fixed_isotropic']]['de76'] - 1):+.1f}%).",
        "",
        "| model | rank | MERL ΔE76 | MERL LogErr | MERL held-out log RMS |",
        "|---|---|---|---|---|",
    ]
    for n, f in sorted(m["fixed"].items(), key=lambda kv: kv[1]["rank"]):
        lines.append(
            f"| {n} | {f['rank']} | {f['de76']:.3f} | {f['logerr']:.4f} | {f['held_out']:.4f} |"
        )
    clean = [r for r in out["analytic"]["rows"] if r["noise"] == 0]
    if clean:
        rbf = [k for k in clean[0]["dense_de76"] if k != "bivariate"]
        chosen = np.mean([r["dense_de76"][r["choice"]] for r in clean])
        best_rbf = np.mean([min(r["dense_de76"][k] for k in rbf) for r in clean])
        best_all = np.mean([min(r["dense_de76"].values()) for r in clean])
        lines += [
            "",
            f"Noise-free analytic set ({len(clean)} models): automatic choice mean ΔE76 "
            f"{chosen:.3f}; the best fixed RBF model per material {best_rbf:.3f}; the best "
            f"fixed model per material, the bivariate model among them, {best_all:.3f}.",
        ]
    t = out["timing"]
    lines += [
        "",
        f"Cost per material (after compilation): select_model {t['select_median_s']:.3f} s "
        f"(isotropic {t['select_iso_median_s']:.3f} s, anisotropic {t['select_aniso_median_s']:.3f} s), reconstruct "
        f"{t['reconstruct_median_s']:.3f} s; first calls (compilation) {t['select_first_s']:.1f} s and {t['reconstruct_first_s']:.1f} s.",
    ]
    return "\n".join(lines) + "\n"


def chart(out, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    m = out["merl"]
    items = sorted(m["fixed"].items(), key=lambda kv: kv[1]["rank"])
    ax = axes[0]
    xs = [f["rank"] for _, f in items]
    ax.plot(xs, [f["de76"] for _, f in items], "o-", label="dense ΔE76 (ground truth)")
    for n, f in items:
        ax.annotate(
            n,
            (f["rank"], f["de76"]),
            fontsize=7,
            rotation=30,
            xytext=(2, 4),
            textcoords="offset points",
        )
    ax.axhline(
        m["auto"]["de76"], color="C3", ls="--", label=f"automatic choice {m['auto']['de76']:.2f}"
    )
    ax2 = ax.twinx()
    ax2.plot(
        xs,
        [f["held_out"] for _, f in items],
        "s:",
        color="C2",
        label="held-out log RMS (own samples)",
    )
    ax2.set_ylabel("held-out log RMS", color="C2")
    ax.set_xlabel("complexity rank")
    ax.set_ylabel("mean ΔE76")
    ax.set_title(f"MERL test ({len(m['materials'])}, isotropic), aniso204 samples")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper left")
    ax = axes[1]
    rows = [r for r in out["analytic"]["rows"] if r["noise"] == 0 and not r["truly_isotropic"]]
    names = list(DEFAULT_ANISO)
    ranks = [CANDIDATES[n].rank for n in names]
    ax.plot(
        ranks,
        [np.mean([r["dense_de76"][n] for r in rows]) for n in names],
        "o-",
        label="dense ΔE76",
    )
    auto = np.mean([r["dense_de76"][r["choice"]] for r in rows])
    ax.axhline(auto, color="C3", ls="--", label=f"automatic choice {auto:.2f}")
    for n, k in zip(names, ranks):
        ax.annotate(
            n,
            (k, np.mean([r["dense_de76"][n] for r in rows])),
            fontsize=7,
            rotation=30,
            xytext=(2, 4),
            textcoords="offset points",
        )
    ax.set_xlabel("complexity rank")
    ax.set_ylabel("mean ΔE76")
    ax.set_title(f"analytic anisotropic ({len(rows)}, synthetic), noise-free")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
