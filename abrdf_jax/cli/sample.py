"""``abrdf-jax sample``: a table, a MERL file or a built-in material → a measurement CSV.

The protocol's slice samples (``PROTOCOL.md``) of a dense table (``.npz``/``.exr``), a MERL BRDF
file (``.binary``, nearest bin) or a named material (``abrdf-jax materials``). The capture flags
(``--per-slice``, ``--pairs``, ``--jitter``, ``--noise``, ``--gap``, ``--seed``) simulate a real,
continuous capture instead (:func:`abrdf_jax.simulate_capture`): they need a model that can be
evaluated at any direction (a material or a MERL file), so a table source refuses them (a table
is only known on the UBO grid).
"""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError
from .._names import BUDGETS, MEASUREMENT_SUFFIXES, TABLE_SUFFIXES
from . import _common as common

MERL_SUFFIX = ".binary"
#: Slice offset α of the samples unless ``--alpha`` says otherwise (PROTOCOL.md: 15°).
DEFAULT_ALPHA = 15.0
#: The flags of a simulated capture: option -> keyword of ``abrdf_jax.simulate_capture``.
CAPTURE_FLAGS = {
    "--per-slice": "per_slice",
    "--pairs": "pairs",
    "--jitter": "jitter_deg",
    "--noise": "noise",
    "--gap": "gap_deg",
    "--seed": "seed",
}


#: The ``--help`` texts: the command's and each option's.
HELP = {
    "help": "table or material -> measurement CSV",
    "description": "Take the protocol's slice samples of a dense table (.npz/.exr), a MERL BRDF "
    "file (.binary, nearest bin) or a built-in material model. The capture flags (--per-slice, "
    "--pairs, --jitter, --noise, --gap, --seed) simulate a real continuous capture "
    "(abrdf_jax.simulate_capture) of a material or a MERL file; a table is only known on the UBO "
    "grid and refuses them.",
    "source": "TABLE.npz, TABLE.exr, a MERL FILE.binary or a material name",
    "--budget": "iso102 (4 diagonal slices) or aniso204 (8 slices); default: iso102 for a "
    "material known to be isotropic, else aniso204",
    "--alpha": f"slice offset in degrees, 0 < DEG < 180 (default {DEFAULT_ALPHA:g})",
    "--per-slice": "samples per slice, evenly spaced: one count for every slice, or one per "
    "elevation pair as a comma list (default: the protocol's 25,25,26,26 at its pairs, 24 "
    "elsewhere)",
    "--pairs": "elevation pairs THETA_I/THETA_V in degrees, comma separated, each in [0, 90) "
    "(default 30/30,30/75,75/30,75/75)",
    "--jitter": "sigma in degrees of the normal error of every angle; the samples are taken and "
    "recorded at the true, deviated angles (default 0)",
    "--noise": "relative sigma of the value noise, y * (1 + FRAC * N(0, 1)) per channel "
    "(default 0)",
    "--gap": "leave out the samples whose light and view directions are less than DEG apart "
    "(the camera occluding the light near retro-reflection; default 0: no gap)",
    "--seed": "seed of the jitter and the noise (default 0)",
}


def register(sub) -> None:
    add = common.adder(
        common.command(sub, "sample", run, HELP["help"], HELP["description"], writes=True), HELP
    )
    add("source", metavar="SOURCE")
    add("-o", "--output", required=True, metavar="MEAS.csv")
    add("--budget", choices=BUDGETS)
    add("--alpha", type=common.alpha_deg, metavar="DEG")
    add("--per-slice", type=_TYPES["--per-slice"], metavar="N[,N...]")
    add("--pairs", type=_TYPES["--pairs"], metavar="TI/TV[,...]")
    add("--jitter", type=_TYPES["--jitter"], metavar="DEG")
    add("--noise", type=_TYPES["--noise"], metavar="FRAC")
    add("--gap", type=_TYPES["--gap"], metavar="DEG")
    add("--seed", type=_TYPES["--seed"], metavar="S")


# --------------------------------------------------------------------------------------------
# The capture flags (parsed and checked before any numerics)
# --------------------------------------------------------------------------------------------


def _per_slice(text: str):
    """One count for every slice (an int) or one per pair (a list) from ``--per-slice``."""
    counts = [common.positive("--per-slice")(p.strip()) for p in text.split(",")]
    return counts[0] if len(counts) == 1 else counts


#: flag -> its argparse ``type=`` (each value checked while the command line is parsed).
_TYPES = {
    "--per-slice": _per_slice,
    "--pairs": common.elevation_pairs,
    "--jitter": common.finite("--jitter", 0.0, open_low=False),
    "--noise": common.finite("--noise", 0.0, open_low=False),
    "--gap": common.finite("--gap", 0.0, open_low=False),
    "--seed": common.integer("--seed", 0),
}
assert _TYPES.keys() == CAPTURE_FLAGS.keys()


def capture_options(args) -> dict[str, object]:
    """``{flag: value}`` of the capture flags given (empty: the protocol's ideal samples).

    Raises:
        InputError: naming --per-slice, when its counts do not match the pairs (each value is
            checked by its ``type=`` while parsing).
    """
    given = {}
    for flag in _TYPES:
        value = getattr(args, flag.lstrip("-").replace("-", "_"))
        if value is not None:
            given[flag] = value
    counts = given.get("--per-slice")
    if isinstance(counts, list):
        n_pairs = len(given["--pairs"]) if "--pairs" in given else 4  # the protocol's four
        if len(counts) != n_pairs:
            raise InputError(
                f"--per-slice gives {len(counts)} counts for {n_pairs} elevation pairs; give "
                "one count, or one per pair"
            )
    return given


def _is_table(source: str) -> bool:
    p = Path(source)
    return p.suffix.lower() != MERL_SUFFIX and (p.suffix.lower() in TABLE_SUFFIXES or p.exists())


def _load_source(source: str):
    """``(model or table, budget it calls for)``: a table file, a MERL file or a material name."""
    from .. import io

    p = Path(source)
    if p.suffix.lower() == MERL_SUFFIX:
        return io.MERLMaterial(io.read_merl_binary(p)), "iso102"  # MERL data are isotropic
    if _is_table(source):
        return io.read_table(p), "aniso204"  # nothing known: measure everything
    from .. import materials

    try:
        model = materials.get_material(source)
    except InputError as e:
        raise InputError(f"{source}: not a table file (.npz/.exr) nor a known material: {e}") from e
    return model, "iso102" if materials.material_info(source)["isotropic"] else "aniso204"


def _describe(capture: dict, left_out: int) -> str:
    """What was simulated, for the console line."""
    parts = []
    for flag, v in capture.items():
        if flag == "--pairs":
            v = ",".join(f"{a:g}/{b:g}" for a, b in v)
        elif flag == "--per-slice" and isinstance(v, list):
            v = ",".join(map(str, v))
        elif isinstance(v, float):
            v = f"{v:g}"
        parts.append(f"{flag} {v}")
    if "--gap" in capture:
        parts.append(f"{left_out} samples in the gap left out")
    return "; simulated capture: " + ", ".join(parts)


def run(args) -> int:
    out = common.check_output_file(Path(args.output), MEASUREMENT_SUFFIXES, "measurement")
    capture = capture_options(args)
    if capture and _is_table(args.source):
        flag = next(iter(capture))
        raise InputError(
            f"{flag}: {args.source} is a table, known only on the UBO grid; a simulated capture "
            "needs a material name or a MERL .binary file"
        )
    import abrdf_jax as aj
    from .. import io

    source, budget = _load_source(args.source)
    budget = args.budget or budget
    alpha = DEFAULT_ALPHA if args.alpha is None else float(args.alpha)
    if capture:
        kwargs = {CAPTURE_FLAGS[flag]: v for flag, v in capture.items()}
        samples = aj.simulate_capture(source, alpha_deg=alpha, budget=budget, **kwargs)
        left_out = 0
        if "--gap" in capture:  # the same capture without the gap, to say what the gap took
            kwargs |= {"gap_deg": 0.0, "noise": 0.0}
            full = aj.simulate_capture(source, alpha_deg=alpha, budget=budget, **kwargs)
            left_out = len(full) - len(samples)
        note = _describe(capture, left_out)
    else:
        config, params = common.params_for(budget, alpha)
        samples, note = aj.sample(source, config, params), ""
    with common.output_lock(out):  # one writer; a killed one's temporary file goes
        io.write_samples_csv(out, samples)
    print(f"{out}: {len(samples)} samples ({budget}, alpha {alpha:g} deg) of {args.source}{note}")
    return 0
