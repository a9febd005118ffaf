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
#: The slice offset α a command accepts, degrees, open at both ends. α and α + 360 are the same
#: slices; at α = 0 the axial slice (φv = φi − α) has light and view at one azimuth, so at the
#: equal-elevation pairs they coincide along the whole slice (the camera shadows the light) and
#: both slice crossings lie there; at α = 180 the axial slice lies in the mirror plane and both
#: crossings on the specular peak; α in (180, 360) is −α, the same slices with light and view
#: swapped. Hence 0 < α < 180 (the protocol's 15 inside).
ALPHA_RANGE = (0.0, 180.0)
KINDS = ("axial", "diagonal")
#: Luminance weights of linear RGB (PROTOCOL.md, metrics item 1: the exposure's Y).
LUMA = (0.2126, 0.7152, 0.0722)


def on_ubo_rings(pairs) -> bool:
    """Whether every elevation of ``pairs`` (degrees) is a UBO ring's (a capture's levels within
    ``_grouping.RING_SNAP_DEG`` of a ring take its elevation): every capture near the rings has
    such pairs, while a level off them is the capture's median rounded to
    ``_grouping.LEVEL_STEP_DEG``, which one device's captures mostly share but a stray one may
    not."""
    return all(float(v) in UBO_THETAS_DEG for pair in pairs for v in pair)


def protocol_counts(budget: str) -> tuple[int, ...]:
    """Per-slice sample counts (axial, diagonal per pair) of a PROTOCOL budget."""
    if budget == "iso102":
        return tuple(c for n in PROTOCOL_COUNTS for c in (0, n))
    if budget == "aniso204":
        return tuple(c for n in PROTOCOL_COUNTS for c in (n, n))
    raise ValueError(f"budget must be 'iso102' or 'aniso204', got {budget!r}")
