"""``abrdf-jax reference``: a built-in material's dense 81×81 table (the reference to evaluate
or render a reconstruction against).

The table is the material evaluated at every UBO2003 (illumination, view) direction pair, as
:func:`abrdf_jax.materials.dense_table` returns it: ``table[i, v, c]``, linear RGB, value =
BRDF · cos θi (``PROTOCOL.md``). ``nbrdf:<merl-name>`` reads a neural MERL fit from the shared
data folder.
"""

from __future__ import annotations

from pathlib import Path

from . import _common as common

#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "write a built-in material's dense reference table",
    "description": "Evaluate a built-in material (see 'abrdf-jax materials') on all 81 x 81 "
    "UBO2003 direction pairs and write the table (.npz or .exr), e.g. as the REF of "
    "'abrdf-jax evaluate REC REF'.",
    "material": "material name (abrdf-jax materials lists them; nbrdf:<merl-name> for the "
    "neural MERL fits in the shared data)",
    "--output": "output table, .npz or .exr (written atomically)",
}


def register(sub) -> None:
    p = common.command(sub, "reference", run, HELP["help"], HELP["description"], writes=True)
    add = common.adder(p, HELP)
    add("material", metavar="MATERIAL")
    add("-o", "--output", required=True, type=Path, metavar="REF.npz")


def run(args) -> int:
    from ..materials import check_name

    check_name(args.material)  # both checked before JAX is imported
    out = common.check_output_file(args.output, (".npz", ".exr"), "table")
    from .. import io, materials

    table = materials.dense_table(args.material)
    common.announce_replace(out)
    io.write_table(out, table)
    print(f"reference: {out} ({args.material}, 81 x 81 x 3, linear RGB, BRDF * cos(theta_i))")
    return 0
