"""``abrdf-jax render``: a table (and its reference) rendered in Mitsuba 3 on a sphere and a
cylinder, with the per-pixel ΔE76 map, as one figure (the ``render`` extra).

The scene (camera, shapes, lights, integrator) is :mod:`abrdf_jax.render`'s ``render_table``;
the figure ``scene_figure``. Every argument and both tables are checked before Mitsuba or JAX
is imported; the figure is written atomically under the output's lock.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .._names import RENDER_LIGHT_CHOICES, RENDER_SIZE_RANGE, RENDER_SPP_RANGE
from .._names import RENDER_SHAPES, RENDER_VARIANTS
from . import _common as common

_FIGURES = (".png", ".pdf", ".svg")
#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "render a table (beside its reference) in Mitsuba 3",
    "description": "Render an ABRDF table in Mitsuba 3 on a sphere and on a cylinder (whose "
    "tangent runs around it, as on a brushed rod, so anisotropy shows) under a procedural "
    "environment and/or a point light; with REFERENCE, the reference beside it and the ΔE76 of "
    "every pixel. Needs the render extra: pip install 'abrdf_jax[render]'.",
    "table": "the table to render (.npz/.exr, 81 x 81 x 3), e.g. a reconstruction",
    "reference": "optional reference table (.npz/.exr): rendered beside, sets the exposure",
    "--output": "the figure, .png (.pdf, .svg), written atomically",
    "--spp": f"samples per pixel, {RENDER_SPP_RANGE[0]} to {RENDER_SPP_RANGE[1]} (default 16)",
    "--size": f"image side in pixels, {RENDER_SIZE_RANGE[0]} to {RENDER_SIZE_RANGE[1]} "
    "(default 64)",
    "--light": "env (procedural sky with a window), point, or both (default env)",
    "--variant": "Mitsuba variant (default scalar_rgb; llvm_ad_rgb is much faster where a "
    "libLLVM works, docs/render.md)",
    "--quiet": "no progress lines",
}


def register(sub) -> None:
    p = common.command(sub, "render", run, HELP["help"], HELP["description"], writes=True)
    add = common.adder(p, HELP)
    add("table", metavar="TABLE")
    add("reference", metavar="REFERENCE", nargs="?")
    add("-o", "--output", required=True, type=Path, metavar="FIG.png")
    add("--spp", type=common.int_in("--spp", *RENDER_SPP_RANGE), default=16, metavar="N")
    add("--size", type=common.int_in("--size", *RENDER_SIZE_RANGE), default=64, metavar="PX")
    add("--light", choices=RENDER_LIGHT_CHOICES, default="env")
    add("--variant", choices=RENDER_VARIANTS, default="scalar_rgb")
    add("-q", "--quiet", action="store_true")


def _note(args, lights) -> str:
    try:
        from importlib.metadata import version

        mitsuba = f"Mitsuba {version('mitsuba')}"
    except Exception:  # noqa: BLE001 - not installed as a distribution
        mitsuba = "Mitsuba 3"
    return (
        f"{mitsuba} {args.variant}, {args.size} x {args.size} px, {args.spp} spp, direct "
        f"illumination; lights: {', '.join(lights)} (abrdf_jax.render.render_table); "
        f"{args.table}" + (f" vs {args.reference}" if args.reference else "")
    )


def run(args) -> int:
    out = common.check_output_file(args.output, _FIGURES, "figure")
    from .. import io

    table = io.read_table(args.table)  # both read and checked (numpy) before Mitsuba and JAX
    reference = None if args.reference is None else io.read_table(args.reference)
    lights = ("env", "point") if args.light == "both" else (args.light,)
    from .. import render

    def progress(shape, light, which, seconds):
        if not args.quiet:
            common.say(
                f"rendered {shape}, {light} light, {which}: {args.size} x {args.size} px, "
                f"{args.spp} spp, {args.variant}, {seconds:.1f} s"
            )

    with common.output_lock(out):
        views = render.render_views(
            table,
            reference,
            shapes=RENDER_SHAPES,
            lights=lights,
            size=args.size,
            spp=args.spp,
            variant=args.variant,
            on_image=progress,
        )
        if reference is not None:
            for view in views:
                e = render.view_error(view)
                print(
                    f"{view.shape}, {view.light}: ΔE76 mean {e['de76_mean']:.2f}, 95th "
                    f"percentile {e['de76_p95']:.2f}, max {e['de76_max']:.2f} over the object's "
                    f"pixels (exposure {e['exposure']:.3g})"
                )
        label = Path(args.table).name
        render.scene_figure([(label, [v for v in views if v.shape == s]) for s in RENDER_SHAPES],
                            out, note=_note(args, lights))  # fmt: skip
    print(f"figure: {out}")
    sys.stdout.flush()
    return 0
