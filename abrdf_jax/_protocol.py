"""PROTOCOL.md's fixed numbers, in a module that imports nothing heavy (no JAX).

The UBO2003 grid's elevations and ring sizes, the protocol's elevation pairs, samples per slice
and slice offset α, and the two slice kinds. :mod:`abrdf_jax._grid` and
:mod:`abrdf_jax._slices` build the geometry on them; the command line's planning reads them
without importing JAX.
"""

from __future__ import annotations

# UBO2003: elevations and the number of azimuths on each ring (PROTOCOL.md).
UBO_THETAS_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0)
UBO_COUNTS = (1, 6, 12, 18, 20, 24)
PROTOCOL_PAIRS = ((30.0, 30.0), (30.0, 75.0), (75.0, 30.0), (75.0, 75.0))
PROTOCOL_COUNTS = (25, 25, 26, 26)
PROTOCOL_ALPHA_DEG = 15.0
KINDS = ("axial", "diagonal")
#: Luminance weights of linear RGB (PROTOCOL.md, metrics item 1: the exposure's Y).
LUMA = (0.2126, 0.7152, 0.0722)


def protocol_counts(budget: str) -> tuple[int, ...]:
    """Per-slice sample counts (axial, diagonal per pair) of a PROTOCOL budget."""
    if budget == "iso102":
        return tuple(c for n in PROTOCOL_COUNTS for c in (0, n))
    if budget == "aniso204":
        return tuple(c for n in PROTOCOL_COUNTS for c in (n, n))
    raise ValueError(f"budget must be 'iso102' or 'aniso204', got {budget!r}")
