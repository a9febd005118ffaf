"""The suite's registry: one :class:`Entry` per configuration on the chart, and entry builders.

Part of the speed/accuracy suite (:mod:`benchmarks.suite`). An entry's ``build`` receives the run's
:class:`~benchmarks._suite_layouts.Context`, its :class:`~benchmarks._suite_layouts.Layout` and the
dtype, and returns the function that is timed.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Callable

import jax.numpy as jnp

import abrdf_jax as aj

from ._common import RESULTS
from ._suite_layouts import LAYOUTS, Batch, Context, Layout


Build = Callable[[Context, Layout, object], Callable[[Batch], object]]


@dataclasses.dataclass(frozen=True)
class Entry:
    """One configuration on the chart.

    Attributes:
        name: unique label.
        group: colour group on the chart (``"paper"``, ``"budget"``, ``"peer: PCA"``, ...).
        layout: name of a :data:`LAYOUTS` entry.
        build: ``build(ctx, layout, dtype) -> run``; everything ``build`` does (training a prior,
            building an operator) is reported as set-up time; ``run(batch)`` is what is timed and
            returns the ``(B, 81, 81, 3)`` tables.
        modes: the run modes that include this entry (``"full"``, ``"quick"``, ``"smoke"``).
        dtype: ``"float32"`` or ``"float64"``.
        datasets: datasets it runs on (``"merl-test"``; ``"analytic-aniso"`` for aniso layouts).
        jit: whether ``run`` compiles on its first call (then a warm-up call precedes the timing).
        note: free text stored with the point.
    """

    name: str
    group: str
    layout: str
    build: Build
    modes: tuple = ("full",)
    dtype: str = "float32"
    datasets: tuple = ("merl-test",)
    jit: bool = True
    note: str = ""


REGISTRY: dict[str, Entry] = {}


def register(entry: Entry) -> Entry:
    """Add (or replace) a configuration in :data:`REGISTRY`."""
    if entry.layout not in LAYOUTS:
        raise ValueError(
            f"entry {entry.name!r}: unknown layout {entry.layout!r}; known: {list(LAYOUTS)}"
        )
    if entry.dtype not in ("float32", "float64"):
        raise ValueError(
            f"entry {entry.name!r}: dtype must be float32 or float64, got {entry.dtype!r}"
        )
    REGISTRY[entry.name] = entry
    return entry


def default_params(config: aj.Config, dtype) -> aj.Params:
    return aj.Params.default(config, dtype=dtype)


def pipeline_entry(
    name, group, layout, *, preset="paper", params=default_params, **config_kw
) -> Entry:
    """An entry that runs ``abrdf_jax``'s batched reconstruction (vmapped, jit-compiled).

    Args:
        preset: a name of :data:`abrdf_jax.PRESETS` (``"paper"``: Gaussian kernel, linear values;
            ``"recommended"``: thin-plate spline, log values); ``config_kw`` override it.
        params: ``(config, dtype) -> Params`` (default: ``Params.default``, chosen on train).
        Other keyword arguments of :class:`Entry` (``modes``, ``dtype``, ``datasets``, ``note``)
        are taken from ``config_kw`` when given.
    """
    entry_kw = {
        k: config_kw.pop(k) for k in ("modes", "dtype", "datasets", "note") if k in config_kw
    }
    if preset not in aj.PRESETS:
        raise ValueError(f"entry {name!r}: unknown preset {preset!r}; known: {list(aj.PRESETS)}")
    base = dict(aj.PRESETS[preset])

    def build(ctx, lay, dtype):
        cfg = lay.config(**{**base, **config_kw})
        p = params(cfg, dtype)
        return lambda batch: aj.reconstruct_batch(batch.meas, cfg, p)

    note = entry_kw.pop("note", "") or f"{preset} preset" + (f", {config_kw}" if config_kw else "")
    return Entry(name, group, layout, build, note=note, **entry_kw)


def params_file_entry(name, group, layout, path, **entry_kw) -> Entry:
    """An entry that reconstructs with the configuration and parameters of a parameter file.

    ``path`` is a JSON file of ``abrdf-jax fit`` / ``abrdf_jax.tuning.save_params`` (e.g. widths
    and λ tuned on the train split); its configuration is used with the layout's pairs, and α is
    the protocol's 15° at which the test samples are taken.
    """
    from abrdf_jax.tuning import load_params

    def build(ctx, lay, dtype):
        cfg, p, _ = load_params(path)
        # the file's method on this layout's budget and elevation pairs
        cfg = dataclasses.replace(cfg, budget=lay.budget, pairs=tuple(lay.pairs))
        # the test samples lie at PROTOCOL's α = 15°: the file's widths and λ are used, not its α
        p = p.astype(dtype).with_alpha_deg(aj.PROTOCOL_ALPHA_DEG)
        return lambda batch: aj.reconstruct_batch(batch.meas, cfg, p)

    return Entry(
        name, group, layout, build, note=entry_kw.pop("note", f"parameters from {path}"), **entry_kw
    )


def tuned_params(budget: str, preset: str, path=None):
    """Widths and λ tuned on the train split (``benchmarks/results/tuning.json``, population LM fit).

    Returns ``(config, dtype) -> Params`` with α = 15° (the protocol's α, at which the test samples
    are taken; the tuned α belongs to re-sampled data), or ``None`` when the file or row is absent.
    """
    path = Path(path or RESULTS / "tuning.json")
    if not path.exists():
        return None
    rows = [
        r
        for r in json.loads(path.read_text()).get("population", [])
        if r.get("budget") == budget and r.get("config") == preset and r.get("solver") == "lm"
    ]
    if not rows:
        return None
    widths, reg = rows[0]["widths"], rows[0]["reg"]

    def params(config, dtype):
        return aj.Params(
            aj.Params.default(dtype=dtype).alpha,
            jnp.asarray(widths, dtype),
            jnp.asarray(reg, dtype),
        )

    return params


def selected_entries(mode: str, only=None) -> list[Entry]:
    """The entries of run mode ``mode``, or (``only``) those whose name contains one of the strings."""
    if only:
        return [e for e in REGISTRY.values() if any(o in e.name for o in only)]
    return [e for e in REGISTRY.values() if mode in e.modes]
