"""``abrdf-jax sample``: a table, a MERL file or a built-in material → a measurement CSV.

The protocol's slice samples (``PROTOCOL.md``) of a dense table (``.npz``/``.exr``), a MERL BRDF
file (``.binary``, nearest bin) or a named material (``abrdf-jax materials``).
"""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError
from .._names import BUDGETS, MEASUREMENT_SUFFIXES, TABLE_SUFFIXES
from . import _common as common

MERL_SUFFIX = ".binary"
#: Slice offset α of the samples unless ``--alpha`` says otherwise (PROTOCOL.md: 15°).
DEFAULT_ALPHA = 15.0


#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "table or material -> measurement CSV",
    "description": "Take the protocol's slice samples of a dense table (.npz/.exr), a MERL BRDF "
    "file (.binary, nearest bin) or a built-in material model.",
    "source": "TABLE.npz, TABLE.exr, a MERL FILE.binary or a material name",
    "--budget": "iso102 (4 diagonal slices) or aniso204 (8 slices); default: iso102 for a "
    "material known to be isotropic, else aniso204",
    "--alpha": f"slice offset in degrees (default {DEFAULT_ALPHA:g})",
}


def register(sub) -> None:
    add = common.adder(common.command(sub, "sample", run, HELP["help"], HELP["description"]), HELP)
    add("source", metavar="SOURCE")
    add("-o", "--output", required=True, metavar="MEAS.csv")
    add("--budget", choices=BUDGETS)
    add("--alpha", type=float, metavar="DEG")


def _load_source(source: str):
    """``(model or table, budget it calls for)``: a table file, a MERL file or a material name."""
    from .. import io

    p = Path(source)
    if p.suffix.lower() == MERL_SUFFIX:
        return io.MERLMaterial(io.read_merl_binary(p)), "iso102"  # MERL data are isotropic
    if p.suffix.lower() in TABLE_SUFFIXES or p.exists():
        return io.read_table(p), "aniso204"  # nothing known: measure everything
    from .. import materials

    try:
        model = materials.get_material(source)
    except InputError as e:
        raise InputError(f"{source}: not a table file (.npz/.exr) nor a known material: {e}") from e
    return model, "iso102" if materials.material_info(source)["isotropic"] else "aniso204"


def run(args) -> int:
    import abrdf_jax as aj
    from .. import io

    out = common.check_output_file(Path(args.output), MEASUREMENT_SUFFIXES, "measurement")
    source, budget = _load_source(args.source)
    budget = args.budget or budget
    alpha = DEFAULT_ALPHA if args.alpha is None else float(args.alpha)
    config, params = common.params_for(budget, alpha)
    samples = aj.sample(source, config, params)
    io.write_samples_csv(out, samples)
    print(f"{out}: {len(samples)} samples ({budget}, alpha {alpha:g} deg) of {args.source}")
    return 0
