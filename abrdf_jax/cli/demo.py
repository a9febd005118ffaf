"""``abrdf-jax demo``: sample → reconstruct → evaluate a few built-in materials, and a figure.

Isotropic materials are measured with the isotropic budget (102 samples, the 4 diagonal slices,
eq. 5) and anisotropic ones with all 8 slices (204 samples), as in the paper's Fig. 4 and 6.
The reference is each model's dense 81×81 table; the samples are taken from the continuous
model at the protocol's exact angles.
"""

from __future__ import annotations

import functools
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
_COLUMNS = (("de76", "dE76", "{:7.2f}"), ("de2000", "dE2000", "{:7.2f}"), ("rmse8", "RMSE8", "{:7.2f}"),
            ("psnr", "PSNR", "{:7.2f}"), ("logerr", "LogErr", "{:7.4f}"))


@functools.lru_cache(maxsize=1)
def _sampler():
    import equinox as eqx

    import abrdf_jax as aj

    return eqx.filter_jit(lambda model, config, params: aj.sample(model, config, params, as_measurements=True))


def _sample_measurements(model, config, params):
    """The protocol's slice samples of a model, grouped into slices, in one compiled call
    (eager sampling dispatches many small operations, which is slower than compiling)."""
    return _sampler()(model, config, params)


def is_isotropic(model, info=None, n: int = 64, seed: int = 0) -> bool:
    """Whether a material model is isotropic.

    Uses ``info["isotropic"]`` (or an ``isotropic`` attribute) when the material's description
    states it; otherwise checks numerically that rotating both directions about the normal
    leaves the value unchanged (relative tolerance 1e-3) at ``n`` random pairs.
    """
    flag = info.get("isotropic") if isinstance(info, dict) else getattr(info, "isotropic", None)
    if isinstance(flag, bool):
        return flag
    import numpy as np

    rng = np.random.default_rng(seed)

    def dirs(phi_shift):
        t = np.radians(rng_t)
        p = np.radians(rng_p + phi_shift)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

    rng_t = rng.uniform(5, 80, (2, n))
    rng_p = rng.uniform(0, 360, (2, n))
    shift = rng.uniform(20, 340)
    a = dirs(0.0)
    b = dirs(shift)
    va = np.asarray(model(a[0].astype(np.float32), a[1].astype(np.float32)), dtype=np.float64)
    vb = np.asarray(model(b[0].astype(np.float32), b[1].astype(np.float32)), dtype=np.float64)
    scale = np.maximum(np.abs(va), np.abs(vb)).max() + 1e-12
    return bool(np.max(np.abs(va - vb)) <= 1e-3 * scale)


def choose_materials(n_materials: int | None = None) -> list[tuple[str, object, str]]:
    """Pick the demo's materials: ``(name, model, budget)``.

    Isotropic and anisotropic materials alternate, so that any ``n_materials >= 2`` shows both
    kinds; by default :data:`N_ISOTROPIC` isotropic and :data:`N_ANISOTROPIC` anisotropic ones.
    """
    from .. import materials

    iso, aniso = [], []
    available = materials.default_materials()
    order = [n for n in PREFERRED if n in available] + [n for n in available if n not in PREFERRED]
    for name in order:
        model = available[name]
        try:
            info = materials.material_info(name)
        except Exception:  # noqa: BLE001 - the numeric check decides
            info = None
        (iso if is_isotropic(model, info) else aniso).append((name, model))
    if n_materials is None:
        iso, aniso = iso[:N_ISOTROPIC], aniso[:N_ANISOTROPIC]
    chosen = []
    for k in range(max(len(iso), len(aniso))):
        if k < len(iso):
            chosen.append((*iso[k], "iso102"))
        if k < len(aniso):
            chosen.append((*aniso[k], "aniso204"))
    if n_materials is not None:
        chosen = chosen[:n_materials]
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
    from ..render._figures import check_figure_path, comparison_figure

    stream = sys.stdout if stream is None else stream
    output = check_figure_path(output)
    if n_materials is not None and n_materials < 1:
        raise InputError(f"n_materials must be at least 1, got {n_materials}")
    chosen = choose_materials(n_materials)

    header = f"{'material':<22} {'budget':<9}" + "".join(f" {label:>7}" for _, label, _ in _COLUMNS)
    print(header + f" {'seconds':>8}", file=stream)
    print("-" * (len(header) + 9), file=stream)
    rows, results = [], []
    compiled: set[str] = set()
    for name, model, budget in chosen:
        config = aj.preset("recommended", budget)
        params = aj.Params.default(config)
        reference = np.asarray(materials.dense_table(model), dtype=np.float32)
        measured = _sample_measurements(model, config, params)
        t0 = time.perf_counter()
        rec = np.asarray(aj.reconstruct(measured, config, params))  # np.asarray blocks until ready
        seconds = time.perf_counter() - t0
        first = budget not in compiled
        compiled.add(budget)
        m = {k: float(v) for k, v in metrics.evaluate(rec, reference).items()}
        results.append(m)
        rows.append((name, reference, rec, m))
        cells = "".join(" " + fmt.format(m[key]) for key, _, fmt in _COLUMNS)
        mark = "*" if first else " "
        print(f"{name:<22} {budget:<9}{cells} {seconds:7.2f}{mark}", file=stream, flush=True)
    mean = {k: float(v) for k, v in metrics.summarize(results).items()}
    cells = "".join(" " + fmt.format(mean[key]) for key, _, fmt in _COLUMNS)
    print("-" * (len(header) + 9), file=stream)
    print(f"{'mean':<22} {'':<9}{cells}", file=stream)
    print("* includes JIT compilation (once per budget); metrics as in PROTOCOL.md", file=stream)
    return comparison_figure(rows, output)


def register(sub) -> None:
    """Add the ``demo`` subcommand to the ``abrdf-jax`` parser."""
    d = sub.add_parser("demo", parents=[common.verbose_parent()],
                       help="sample, reconstruct and evaluate built-in materials",
                       description="Sample -> reconstruct -> evaluate a few built-in materials, print a "
                       "table and save a comparison figure.")
    d.add_argument("-o", "--output", default="abrdf_demo.png", metavar="FIGURE.png")
    d.add_argument("--materials", type=int, metavar="N", help="number of materials (default: all demo ones)")
    d.set_defaults(func=run)


def run(args) -> int:
    if args.materials is not None and args.materials < 1:
        raise InputError(f"--materials must be at least 1, got {args.materials}")
    path = run_demo(args.output, n_materials=args.materials, stream=sys.stdout)
    print(f"figure: {path}")
    return 0
