"""``abrdf-jax demo``: sample → reconstruct → evaluate a few built-in materials, and a figure.

Isotropic materials are measured with the isotropic budget (102 samples, the 4 diagonal slices,
eq. 5) and anisotropic ones with all 8 slices (204 samples), as in the paper's Fig. 4 and 6.
The reference is each model's dense 81×81 table; the samples are taken from the continuous
model at the protocol's exact angles.
"""

from __future__ import annotations

import functools
import itertools
import sys
import time
from pathlib import Path
from typing import TextIO

from .._errors import InputError
from . import _common as common

# How many of each kind the demo shows by default, and which come first when present.
N_ISOTROPIC = 2
N_ANISOTROPIC = 3
PREFERRED = ("ggx-plastic", "ward-brushed-steel", "lambert-clay", "ashikhmin-satin", "rough-fabric")
_FORMATS = {key: "{:7.4f}" if key == "logerr" else "{:7.2f}" for key in common.METRICS}
#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "sample, reconstruct and evaluate built-in materials",
    "description": "Sample -> reconstruct -> evaluate a few built-in materials, print a table "
    "and save a comparison figure.",
    "--materials": "number of materials (default: all demo ones)",
}


@functools.cache
def _sampler():
    """The protocol's slice samples of a model, grouped into slices, in one compiled call
    (eager sampling dispatches many small operations, which is slower than compiling)."""
    import equinox as eqx

    import abrdf_jax as aj

    return eqx.filter_jit(
        lambda m, config, params: aj.sample(m, config, params, as_measurements=True)
    )


def choose_materials(n_materials: int | None = None) -> list[tuple[str, object, str]]:
    """Pick the demo's materials: ``(name, model, budget)``.

    Isotropic and anisotropic materials (as the catalogue says) alternate, so that any
    ``n_materials >= 2`` shows both kinds; by default :data:`N_ISOTROPIC` isotropic and
    :data:`N_ANISOTROPIC` anisotropic ones.
    """
    from .. import materials

    available = materials.default_materials()
    order = [n for n in PREFERRED if n in available] + [n for n in available if n not in PREFERRED]
    iso = [(n, "iso102") for n in order if materials.material_info(n)["isotropic"]]
    aniso = [(n, "aniso204") for n in order if not materials.material_info(n)["isotropic"]]
    if n_materials is None:
        iso, aniso = iso[:N_ISOTROPIC], aniso[:N_ANISOTROPIC]
    both = [x for pair in itertools.zip_longest(iso, aniso) for x in pair if x is not None]
    chosen = [(n, available[n], budget) for n, budget in both][:n_materials]
    if not chosen:
        raise InputError("no built-in materials to show")
    return chosen


def run_demo(
    output: str | Path = "abrdf_demo.png",
    n_materials: int | None = None,
    stream: TextIO | None = None,
) -> Path:
    """Sample, reconstruct and evaluate built-in materials; print a table; save a figure.

    Args:
        output: the comparison figure (``.png``; ``.pdf``/``.svg`` also work), written atomically.
        n_materials: how many materials (default: 2 isotropic and 3 anisotropic).
        stream: where the table goes (default ``sys.stdout``).

    Returns:
        The path of the figure.

    Raises:
        InputError: a bad output path (checked before any work) or ``n_materials < 1``.
    """
    import numpy as np

    import abrdf_jax as aj

    from .. import materials, metrics
    from ..render._comparison import check_figure_path, comparison_figure

    stream = sys.stdout if stream is None else stream
    output = check_figure_path(output)
    if n_materials is not None and n_materials < 1:
        raise InputError(f"n_materials must be at least 1, got {n_materials}")
    chosen = choose_materials(n_materials)

    header = f"{'material':<22} {'budget':<9}" + "".join(
        f" {x:>7}" for x in common.METRICS.values()
    )
    print(header + f" {'seconds':>8}", file=stream)
    print("-" * (len(header) + 9), file=stream)
    rows, results = [], []
    compiled: set[str] = set()
    for name, model, budget in chosen:
        config = aj.preset("recommended", budget)
        params = aj.Params.default(config)
        reference = np.asarray(materials.dense_table(model), dtype=np.float32)
        measured = _sampler()(model, config, params)
        t0 = time.perf_counter()
        rec = np.asarray(aj.reconstruct(measured, config, params))  # np.asarray blocks until ready
        seconds = time.perf_counter() - t0
        mark = " " if budget in compiled else "*"
        compiled.add(budget)
        m = {k: float(v) for k, v in metrics.evaluate(rec, reference).items()}
        results.append(m)
        rows.append((name, reference, rec, m, model))  # the model draws the exact sphere
        cells = "".join(" " + fmt.format(m[key]) for key, fmt in _FORMATS.items())
        print(f"{name:<22} {budget:<9}{cells} {seconds:7.2f}{mark}", file=stream, flush=True)
    mean = {k: float(v) for k, v in metrics.summarize(results).items()}
    cells = "".join(" " + fmt.format(mean[key]) for key, fmt in _FORMATS.items())
    print("-" * (len(header) + 9), file=stream)
    print(f"{'mean':<22} {'':<9}{cells}", file=stream)
    print("* includes JIT compilation (once per budget); metrics as in PROTOCOL.md", file=stream)
    return comparison_figure(rows, output)


def register(sub) -> None:
    add = common.adder(
        common.command(sub, "demo", run, HELP["help"], HELP["description"], writes=True), HELP
    )
    add("-o", "--output", default="abrdf_demo.png", type=common.output_path, metavar="FIGURE.png")
    add("--materials", type=common.positive("--materials"), metavar="N")


def run(args) -> int:
    common.announce_replace(Path(args.output))
    path = run_demo(args.output, n_materials=args.materials, stream=sys.stdout)
    print(f"figure: {path}")
    return 0
