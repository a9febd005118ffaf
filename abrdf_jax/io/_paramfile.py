"""Fitted parameters as JSON: what ``abrdf-jax fit`` writes and ``reconstruct --params`` reads.

Layout (``format`` guards against reading something else)::

    {
      "format": "abrdf_jax.params/1",
      "config": {"budget": "iso102", "kernel": "thin_plate_spline", ...},
      "params": {"alpha_deg": 15.0, "widths": [w1, w2, w3, w4], "reg": 0.001},
      "fit": {...}            # free-form provenance: mode, solver, losses, data, date, version
    }
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from .._config import Config
from .._smoothing import smoothing_from_json, smoothing_to_json

if TYPE_CHECKING:  # the traced parameters (JAX): made only when a file is read
    from .._params import Params

FORMAT = "abrdf_jax.params/1"
_CONFIG_FIELDS = (
    "budget",
    "rule",
    "kernel",
    "degree",
    "parameterization",
    "interp",
    "value_space",
    "log_eps",
    "slice_count",
)


def params_to_dict(config: Config, params: "Params", fit: dict | None = None) -> dict:
    """The JSON-ready dictionary of a configuration and its parameters."""
    cfg = {k: getattr(config, k) for k in _CONFIG_FIELDS}
    cfg["pairs"] = [list(map(float, p)) for p in config.pairs]
    cfg["spike_cap"] = None if config.spike_cap is None else [float(v) for v in config.spike_cap]
    cfg["slice_smoothing"] = smoothing_to_json(config.slice_smoothing)
    widths = [float(w) for w in np.asarray(params.widths)]
    values = [params.alpha_deg, float(params.reg), *widths]
    if not all(math.isfinite(v) for v in values):
        raise InputError(
            f"refusing to save non-finite parameters: alpha={params.alpha_deg}, widths={widths}, reg={float(params.reg)}"
        )
    return {
        "format": FORMAT,
        "config": cfg,
        "params": {"alpha_deg": params.alpha_deg, "widths": widths, "reg": float(params.reg)},
        "fit": fit or {},
    }


def save_params(path, config: Config, params: "Params", fit: dict | None = None) -> Path:
    """Write ``config`` and ``params`` (and the fit's provenance) to ``path`` atomically."""
    from ._atomic import atomic_write

    path = Path(path)
    payload = json.dumps(params_to_dict(config, params, fit), indent=2)
    with atomic_write(path, "w") as fh:
        fh.write(payload + "\n")
    return path


def params_from_dict(d: dict, where: str = "parameters") -> tuple[Config, "Params", dict]:
    """Inverse of :func:`params_to_dict`, with errors naming ``where`` and the field."""
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise InputError(
            f"{where}: not an abrdf_jax parameter file (format {got!r}, expected {FORMAT!r})"
        )
    try:
        c, p = dict(d["config"]), d["params"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{where}: missing section {exc}") from None
    unknown = set(c) - set(_CONFIG_FIELDS) - {"pairs", "spike_cap", "slice_smoothing"}
    if unknown:
        raise InputError(f"{where}: unknown config field(s) {sorted(unknown)}")
    if "pairs" in c:
        c["pairs"] = tuple(tuple(float(t) for t in pair) for pair in c["pairs"])
    if isinstance(c.get("spike_cap"), list):  # JSON has no tuples (absent: the default)
        c["spike_cap"] = tuple(c["spike_cap"])
    if "slice_smoothing" in c:
        c["slice_smoothing"] = smoothing_from_json(c["slice_smoothing"])
    if "log_eps" in c:
        c["log_eps"] = float(c["log_eps"])
    try:
        config = Config(**c)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: bad config: {exc}") from None
    try:
        alpha, widths, reg = float(p["alpha_deg"]), [float(w) for w in p["widths"]], float(p["reg"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"{where}: bad params section ({exc!r}); need alpha_deg, widths[4], reg"
        ) from None
    if len(widths) != 4:
        raise InputError(f"{where}: params.widths must have 4 entries, got {len(widths)}")
    if (
        not (0 < alpha < 90)
        or not all(w > 0 and math.isfinite(w) for w in widths)
        or not (reg >= 0 and math.isfinite(reg))
    ):
        raise InputError(
            f"{where}: parameters out of range: alpha_deg={alpha} (0, 90), widths={widths} (> 0), reg={reg} (>= 0)"
        )
    import jax.numpy as jnp

    dt = jnp.zeros(()).dtype
    from .._params import Params

    params = Params(
        jnp.asarray(np.deg2rad(alpha), dt), jnp.asarray(widths, dt), jnp.asarray(reg, dt)
    )
    return config, params, dict(d.get("fit") or {})


def load_params(path) -> tuple[Config, "Params", dict]:
    """Read a parameter file written by :func:`save_params` (or ``abrdf-jax fit``)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read parameter file ({exc.strerror or exc})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    return params_from_dict(d, str(path))
