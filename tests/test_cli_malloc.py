"""The command line keeps freed large blocks for reuse (abrdf_jax.cli._malloc): a loop of numpy
temporaries stops faulting its pages in on every pass; a user's own setting wins."""

import subprocess
import sys

import pytest

from tests.cli_runner import REPO

_LOOP = """
import resource, sys
import numpy as np
from abrdf_jax.cli._malloc import keep_freed_blocks

def faults_per_pass():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(200):
        x = np.ones((2048, 102)); y = x * 2; del x, y
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 200

a = faults_per_pass()
kept = keep_freed_blocks()
print(a, kept, faults_per_pass())
"""


def _run(env_extra=None):
    import os

    env = {**os.environ, "PYTHONPATH": str(REPO), **(env_extra or {})}
    for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"):
        if env_extra is None or k not in env_extra:
            env.pop(k, None)
    out = subprocess.run(
        [sys.executable, "-c", _LOOP], env=env, capture_output=True, text=True, check=True
    )
    before, kept, after = out.stdout.split()
    return float(before), kept == "True", float(after)


def test_large_temporaries_reuse_freed_memory():
    before, kept, after = _run()
    if not kept:
        pytest.skip("not glibc: the allocator's thresholds are not set")
    # two 1.6 MiB arrays a pass: ~800 pages faulted in again every pass without the thresholds
    assert after < 0.05 * max(before, 100.0), (before, after)


def test_a_users_own_threshold_wins():
    _, kept, _ = _run({"MALLOC_MMAP_THRESHOLD_": "65536"})
    assert not kept
