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


_BIG = """
import resource
import numpy as np
from abrdf_jax.cli._malloc import keep_freed_blocks

def faults_per_pass():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(20):
        x = np.ones(6 * 2**20); del x  # 48 MiB: above glibc's own mmap ceiling
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20

keep_freed_blocks()
a = faults_per_pass()
print(a, keep_freed_blocks(largest=48 * 2**20), faults_per_pass())
"""


def test_a_commands_largest_block_is_kept():
    """``keep_freed_blocks(largest)`` (``btf reconstruct``'s chunk outputs) raises the thresholds
    above a block that the default ones leave to ``mmap``: it stops faulting its pages in again."""
    import os

    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
    }
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run(
        [sys.executable, "-c", _BIG], env=env, capture_output=True, text=True, check=True
    )
    before, kept, after = out.stdout.split()
    if kept != "True":
        pytest.skip("not glibc: the allocator's thresholds are not set")
    # 48 MiB = 12,288 pages, faulted in again every pass when the block is mapped anew (~540
    # faults a pass here: the kernel maps anonymous memory in folios of several pages)
    assert float(before) > 100 and float(after) < 0.2 * float(before), (before, after)
