"""The machine's load average as every benchmark stores it (standard library only, so that
benchmarks and children that must not import JAX can read it too)."""

from __future__ import annotations

import os


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages, rounded: stored beside every timing."""
    return [round(x, 2) for x in os.getloadavg()]
