"""The fused model's fixed hyper-parameters as plain numbers (numpy only, no JAX): what a prior
file carries for ``reconstruct --model fused``, the package's defaults, and their checks.

A prior file may hold them in its metadata as ``"fused"`` (a JSON object, format
``abrdf_jax.prior/1`` unchanged: the member is optional, older readers ignore it)::

    {"coords": "halfdiff", "kernel": "matern52", "widths": [ℓ, ...], "sigma_p": σ_p,
     "sigma_k": σ_k, "sigma_n": σ_n, "reference": "log", "chosen_on": "..."}

A prior without it uses :data:`FUSED_DEFAULTS`: the default prior's own numbers, chosen on the
MERL *train* split only (``python -m benchmarks.fused_defaults``; docs/prior.md, "Fused model on
the command line"). With these fixed numbers the fused posterior mean is linear in the mapped
samples, so the command line runs it as one numpy operator per layout
(:mod:`abrdf_jax._fused_entry`).
"""

from __future__ import annotations

import math

#: Width groups of each coordinate system (:data:`abrdf_jax.prior.COORDINATES` uses them).
WIDTH_NAMES = {
    "onion": ("alpha", "beta"),
    "halfdiff": ("theta_h", "phi_h", "theta_d", "phi_d"),
}
#: Covariance kernels (:data:`abrdf_jax.prior.COVARIANCES` has one function per name).
KERNELS = ("gaussian", "matern32", "matern52")
#: How the prior's reference is interpolated at the samples (``prior_at_samples``).
REFERENCES = ("linear", "log")
SCALES = ("sigma_p", "sigma_k", "sigma_n")

#: The default prior's fused hyper-parameters (``python -m benchmarks.fused_defaults``, 12 Adam
#: steps on the mean ΔE76 of the 54 MERL train materials from their exact iso102 samples with the
#: default prior, from the MERL-train population fit of ``benchmarks.fused --quick``: train
#: ΔE76 2.00 → 1.81, prior alone 2.35; rounded to 3 digits; the test split is never read). Also
#: the numbers of any prior file that carries none.
FUSED_DEFAULTS = {
    "coords": "halfdiff",
    "kernel": "matern52",
    "widths": [0.181, 6.84, 0.457, 1.43],
    "sigma_p": 2.18,
    "sigma_k": 0.274,
    "sigma_n": 0.0521,
    "reference": "log",
    "chosen_on": "MERL train split (54 materials, iso102), default prior; "
    "python -m benchmarks.fused_defaults",
}


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def check_fused(d) -> str | None:
    """What is wrong with a ``"fused"`` metadata object (``None``: nothing)."""
    if not isinstance(d, dict):
        return "not a JSON object"
    coords, kernel = d.get("coords"), d.get("kernel")
    if coords not in WIDTH_NAMES:
        return f"coords {coords!r}, expected one of {', '.join(WIDTH_NAMES)}"
    if kernel not in KERNELS:
        return f"kernel {kernel!r}, expected one of {', '.join(KERNELS)}"
    if d.get("reference", "log") not in REFERENCES:
        return f"reference {d.get('reference')!r}, expected one of {', '.join(REFERENCES)}"
    widths, g = d.get("widths"), len(WIDTH_NAMES[coords])
    if not isinstance(widths, list) or len(widths) != g or not all(map(_positive, widths)):
        return f"widths {widths!r}, expected {g} numbers > 0 ({', '.join(WIDTH_NAMES[coords])})"
    for name in SCALES:
        if not _positive(d.get(name)):
            return f"{name} {d.get(name)!r}, expected a number > 0"
    return None


def fused_settings(meta: dict) -> dict:
    """The fused hyper-parameters of a prior's metadata (checked by the file reader), else
    :data:`FUSED_DEFAULTS`; ``"origin"`` says which."""
    own = meta.get("fused")
    if own is None:
        return {**FUSED_DEFAULTS, "origin": "package defaults (the prior file has none)"}
    return {"reference": "log", **own, "origin": "the prior file's own"}
