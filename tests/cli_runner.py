"""The one way the tests run ``abrdf-jax`` in a subprocess: this checkout's package first on the path."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd, timeout: int = 300):
    """``python -m abrdf_jax.cli ARGS`` in ``cwd``: the completed process (text output)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(
        [sys.executable, "-m", "abrdf_jax.cli", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
