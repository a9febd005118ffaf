"""The one way the tests run ``abrdf-jax`` in a subprocess: this checkout's package first on the path."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd, timeout: int = 300):
    """``python -m abrdf_jax.cli ARGS`` in ``cwd``: the completed process (text output)."""
    return run_module("abrdf_jax.cli", *args, cwd=cwd, timeout=timeout)


def run_module(module: str, *args, cwd, timeout: int = 300):
    """``python -m MODULE ARGS`` in ``cwd`` with this checkout first on the path."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


_MAIN_CASES = r"""
import json, sys
from abrdf_jax.cli import main
report = []
for argv, _ in json.loads(sys.argv[1]):
    try:
        code = main(argv)
    except SystemExit as e:  # not expected: main returns the status
        code = ("SystemExit", e.code)
    report.append([argv, code, "jax" in sys.modules])
print(json.dumps(report))
"""


def run_main_cases(cases, cwd, timeout: int = 120):
    """Run ``abrdf_jax.cli.main(argv)`` for each ``(argv, _)`` of ``cases`` in turn in one fresh
    interpreter in ``cwd``: ``([argv, exit status, whether jax is imported after it], ...)``
    and the interpreter's stderr (how the tests prove that a path imports no JAX)."""
    import json

    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", _MAIN_CASES, json.dumps(cases)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


def assert_cli_table(table, samples, config, params):
    """A table the CLI wrote equals the float64 pipeline's on the same samples.

    The CLI runs linear settings through the compiled operator, whose matrix is built in float64
    and stored in float32 (abrdf_jax._engine, docs/cache.md): it agrees with the float64
    pipeline to float32 rounding of the matrix and the data (about 1e-6 of the table's maximum),
    closer than the float32 pipeline does (about 3e-4). Nonlinear settings run the float32
    pipeline, hence the tolerance of 1e-3 of the maximum.
    """
    import numpy as np

    import abrdf_jax as aj

    meas, _ = aj.group_slices(samples, params.alpha_deg, dtype=np.float64)
    expected = np.asarray(aj.reconstruct(meas, config, params.astype(np.float64)))
    np.testing.assert_allclose(table, expected, rtol=0, atol=1e-3 * float(expected.max()))
