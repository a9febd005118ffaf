"""The argparse ``type=`` validators of every subcommand: numbers with their allowed range, angles,
and paths that must exist, in one place (used through :mod:`abrdf_jax.cli._common`).

Each validator checks one argument while argparse parses the command line, before any file is
read and without importing JAX; a bad value exits with status 2 and one line naming the argument
and what it accepts (``abrdf-jax sample: error: argument --jitter: --jitter must be a finite
number in [0, inf), got 'nan'``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .._protocol import ALPHA_RANGE


def integer(name: str, low: int | None = None, high: int | None = None):
    """An integer in ``[low, high]`` (either end open when ``None``), named ``name``."""

    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got {text!r}") from None
        if low is not None and high is not None and not low <= v <= high:
            raise argparse.ArgumentTypeError(f"{name} must be in [{low}, {high}], got {v}")
        if low is not None and v < low:
            raise argparse.ArgumentTypeError(f"{name} must be at least {low}, got {v}")
        if high is not None and v > high:
            raise argparse.ArgumentTypeError(f"{name} must be at most {high}, got {v}")
        return v

    return parse


def positive(name: str):
    """An integer ``>= 1`` (a size, a count, a number of chunks), named ``name``."""
    return integer(name, 1)


def int_in(name: str, low: int, high: int):
    """An integer in ``[low, high]``, named ``name``."""
    return integer(name, low, high)


def finite(name: str, low: float | None = None, high: float | None = None, open_low=True):
    """A finite number, optionally in ``(low, high)`` (``[low, ...`` with ``open_low=False``),
    named ``name`` in its message with the allowed range."""
    lo = "" if low is None else ("(" if open_low else "[") + f"{low:g}"
    hi = "" if high is None else f"{high:g})"
    allowed = f"in {lo or '(-inf'}, {hi or 'inf)'}" if low is not None or high is not None else ""

    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{name} must be a number{' ' + allowed if allowed else ''}, got {text!r}"
            ) from None
        bad_low = low is not None and (v <= low if open_low else v < low)
        if not math.isfinite(v) or bad_low or (high is not None and v >= high):
            raise argparse.ArgumentTypeError(
                f"{name} must be a finite number{' ' + allowed if allowed else ''}, got {text!r}"
            )
        return v

    return parse


def alpha_deg(text):
    """The ``--alpha`` ``type=``: a slice offset in degrees inside
    :data:`abrdf_jax._protocol.ALPHA_RANGE` (why: its comment)."""
    return finite("--alpha (slice offset, degrees)", *ALPHA_RANGE)(text)


def degrees(name: str):
    """Any finite angle in degrees (an offset added to azimuths), named ``name``."""
    return finite(f"{name} (degrees)")


# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------

_KINDS = {"file": Path.is_file, "folder": Path.is_dir, "file or folder": Path.exists}


def existing(kind: str = "file"):
    """A path that exists and is a ``kind`` (``"file"``, ``"folder"`` or ``"file or folder"``)."""
    is_kind = _KINDS[kind]

    def parse(text):
        p = Path(text)
        if not p.exists():
            raise argparse.ArgumentTypeError(f"{p}: not found (expected a {kind})")
        if not is_kind(p):
            found = "a folder" if p.is_dir() else "a file"
            raise argparse.ArgumentTypeError(f"{p}: is {found}, expected a {kind}")
        return p

    return parse


def output_path(text):
    """An output file or folder whose parent folder exists (what the output is, the command
    checks itself)."""
    p = Path(text)
    if not p.parent.is_dir():
        raise argparse.ArgumentTypeError(f"{p}: parent folder {p.parent} does not exist")
    return p


def elevation_pairs(text: str) -> list[tuple[float, float]]:
    """The elevation pairs of ``--pairs`` (``TI/TV,TI/TV,...``), each elevation in [0, 90)."""
    pairs = []
    for item in text.split(","):
        halves = item.split("/")
        if len(halves) != 2:
            raise argparse.ArgumentTypeError(f"{item!r} is not an elevation pair THETA_I/THETA_V")
        try:
            pair = tuple(float(h) for h in halves)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{item!r} is not an elevation pair of numbers"
            ) from None
        if not all(math.isfinite(t) and 0 <= t < 90 for t in pair):
            raise argparse.ArgumentTypeError(
                f"elevations must lie in [0, 90) degrees, got {item!r}"
            )
        pairs.append(pair)
    if len(set(pairs)) != len(pairs):
        raise argparse.ArgumentTypeError(f"an elevation pair is given twice in {text!r}")
    return pairs
