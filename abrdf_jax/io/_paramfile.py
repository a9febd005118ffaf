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
from .._protocol import ALPHA_RANGE
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


def _field(where: str, name: str, message: str) -> InputError:
    return InputError(f"{where}: field {name!r}: {message}")


def _number(value, where: str, name: str, ok, expected: str) -> float:
    """``value`` as a float when it is a finite JSON number (not a bool) and ``ok(value)``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _field(where, name, f"{value!r} is not a number; expected {expected}")
    if not (math.isfinite(value) and ok(value)):
        raise _field(where, name, f"{value!r}, expected {expected}")
    return float(value)


def _numbers(value, where: str, name: str, n: int, ok, expected: str) -> list[float]:
    """A JSON list of ``n`` numbers, each checked by :func:`_number` (``name[k]`` in messages)."""
    if not isinstance(value, list) or len(value) != n:
        got = f"{len(value)} entries" if isinstance(value, list) else repr(value)
        raise _field(where, name, f"expected a list of {n} numbers, got {got}")
    return [_number(v, where, f"{name}[{k}]", ok, expected) for k, v in enumerate(value)]


def _section(d: dict, key: str, where: str) -> dict:
    if key not in d:
        raise _field(where, key, "missing")
    if not isinstance(d[key], dict):
        raise _field(where, key, f"expected a JSON object, got {type(d[key]).__name__}")
    return dict(d[key])


def _config(c: dict, where: str) -> Config:
    """The ``config`` section, each field's JSON type and range checked, then :class:`Config`'s
    own checks (choices, the kernel's degree), each naming the field."""
    unknown = set(c) - set(_CONFIG_FIELDS) - {"pairs", "spike_cap", "slice_smoothing"}
    if unknown:
        raise _field(where, "config", f"unknown field(s) {sorted(unknown)}")
    for key in ("budget", "rule", "kernel", "parameterization", "interp", "value_space"):
        if key in c and not isinstance(c[key], str):
            raise _field(where, f"config.{key}", f"{c[key]!r}, expected a name (a string)")
    for key, low in (("degree", -1), ("slice_count", 2)):  # degree -1: no polynomial tail
        value = c.get(key)
        if value is None and key == "degree":
            continue
        if key in c and (isinstance(value, bool) or not isinstance(value, int) or value < low):
            raise _field(where, f"config.{key}", f"{value!r}, expected an integer >= {low}")
    if "log_eps" in c:
        c["log_eps"] = _number(c["log_eps"], where, "config.log_eps", lambda v: v > 0, "> 0")
    if "pairs" in c:
        pairs = c["pairs"]
        if not isinstance(pairs, list) or not pairs:
            raise _field(where, "config.pairs", f"{pairs!r}, expected a list of [theta_i, theta_v]")
        c["pairs"] = tuple(
            tuple(_numbers(p, where, f"config.pairs[{k}]", 2, lambda t: 0 <= t < 90, "in [0, 90)"))
            for k, p in enumerate(pairs)
        )
    if c.get("spike_cap") is not None:  # JSON has no tuples (absent: the default)
        c["spike_cap"] = tuple(
            _numbers(c["spike_cap"], where, "config.spike_cap", 2, lambda v: v >= 0, ">= 0")
        )
    if "slice_smoothing" in c:  # a number, a list of three or null; Config checks the values
        c["slice_smoothing"] = smoothing_from_json(c["slice_smoothing"])
    try:
        return Config(**c)
    except (TypeError, ValueError) as exc:
        raise _field(where, "config", str(exc)) from None


def params_from_dict(d: dict, where: str = "parameters") -> tuple[Config, "Params", dict]:
    """Inverse of :func:`params_to_dict` (:func:`check_params_dict`, then the traced
    :class:`~abrdf_jax.Params`)."""
    config, values, fit = check_params_dict(d, where)
    return config, _as_params(values), fit


def _as_params(values: dict) -> "Params":
    """Checked parameter values as :class:`~abrdf_jax.Params` in JAX's default float dtype."""
    import jax.numpy as jnp

    from .._params import Params

    dt = jnp.zeros(()).dtype
    alpha = jnp.asarray(np.deg2rad(values["alpha_deg"]), dt)
    return Params(alpha, jnp.asarray(values["widths"], dt), jnp.asarray(values["reg"], dt))


def check_params_dict(d: dict, where: str = "parameters") -> tuple[Config, dict, dict]:
    """The configuration, the parameter values (``alpha_deg``, ``widths``, ``reg``: floats) and
    the fit's provenance of a parameter file's dictionary (numpy only: no JAX): every field checked (JSON type, range, finiteness), the
    errors naming ``where`` and the field (``p.json: field 'params.widths[2]': -1.0, expected a
    finite number > 0``).

    Raises:
        InputError: another format or version, a missing section or field, a value of the
            wrong type or out of range (α outside :data:`abrdf_jax._protocol.ALPHA_RANGE`, a
            width <= 0, λ < 0, NaN or infinity anywhere).
    """
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise InputError(
            f"{where}: not an abrdf_jax parameter file (format {got!r}, expected {FORMAT!r})"
        )
    config = _config(_section(d, "config", where), where)
    p = _section(d, "params", where)
    for key in ("alpha_deg", "widths", "reg"):
        if key not in p:
            raise _field(where, f"params.{key}", "missing")
    lo, hi = ALPHA_RANGE
    alpha = _number(p["alpha_deg"], where, "params.alpha_deg", lambda a: lo < a < hi,
                    f"a slice offset in ({lo:g}, {hi:g}) degrees")  # fmt: skip
    widths = _numbers(p["widths"], where, "params.widths", 4, lambda w: w > 0, "a width > 0")
    reg = _number(p["reg"], where, "params.reg", lambda r: r >= 0, "a regularisation >= 0")
    fit = d.get("fit") or {}
    if not isinstance(fit, dict):
        raise _field(where, "fit", f"expected a JSON object, got {type(fit).__name__}")
    return config, {"alpha_deg": alpha, "widths": widths, "reg": reg}, dict(fit)


def read_params_file(path) -> tuple[Config, dict, dict]:
    """A parameter file's checked content, numpy only (:func:`check_params_dict`): what the
    command line reads before any work."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or exc
        raise InputError(f"{path}: cannot read parameter file ({why})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    return check_params_dict(d, str(path))


def load_params(path) -> tuple[Config, "Params", dict]:
    """Read a parameter file written by :func:`save_params` (or ``abrdf-jax fit``).

    Raises:
        InputError: as :func:`check_params_dict`, naming the file and the field.
    """
    config, values, fit = read_params_file(path)  # every check before JAX is imported
    return config, _as_params(values), fit
