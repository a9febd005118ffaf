"""How the tests run ``abrdf-jax``: in a subprocess (this checkout's package first on the path), or
``main`` in this process (:func:`call_cli`)."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd, timeout: int = 300):
    """``python -m abrdf_jax.cli ARGS`` in ``cwd``: the completed process (text output)."""
    return run_module("abrdf_jax.cli", *args, cwd=cwd, timeout=timeout)


def _x64_off():
    import jax

    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(False)
    from jax.experimental import disable_x64  # JAX before 0.7

    return disable_x64()


def call_cli(*args, cwd) -> subprocess.CompletedProcess:
    """``abrdf_jax.cli.main(ARGS)`` in THIS process, in ``cwd``, its stdout and stderr captured:
    what :func:`run_cli` returns (exit status, text output), without a fresh interpreter, so
    JAX's import and the functions compiled by earlier calls are reused. JAX runs as in the
    command's own process: 64-bit types off (the tests turn them on; ``abrdf-jax`` does not).
    For tests whose subject is the command's behaviour; a test about the process itself (what it
    imports, signals, kills, runs at the same time, its environment) keeps :func:`run_cli`."""
    import contextlib
    import io

    from abrdf_jax.cli import main

    argv = list(map(str, args))
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with (
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            _x64_off(),
        ):
            code = main(argv)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["abrdf-jax", *argv], code, out.getvalue(), err.getvalue())


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def start_cli(*args, cwd) -> subprocess.Popen:
    """``python -m abrdf_jax.cli ARGS`` started in ``cwd`` (text pipes), not waited for: for
    processes that must run at the same time."""
    return subprocess.Popen(
        [sys.executable, "-m", "abrdf_jax.cli", *map(str, args)],
        cwd=cwd,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def run_module(module: str, *args, cwd, timeout: int = 300):
    """``python -m MODULE ARGS`` in ``cwd`` with this checkout first on the path."""
    env = _env()
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


def assert_cli_table(table, samples, config, params, atol: float = 1e-3):
    """A table the CLI wrote equals the float64 pipeline's on the same samples, to ``atol`` of
    its maximum.

    The CLI runs linear settings (and filip2012 on the log of the samples, in two stages)
    through the compiled operator, whose matrix is built in float64 and stored in float32
    (abrdf_jax._engine, docs/cache.md): it agrees with the float64 pipeline to float32 rounding
    of the matrix and the data (about 1e-6 of the table's maximum), closer than the float32
    pipeline does (about 3e-4). Other nonlinear settings run the float32 pipeline, hence the
    default tolerance of 1e-3 of the maximum.
    """
    import numpy as np

    import abrdf_jax as aj

    meas, _ = aj.group_slices(samples, params.alpha_deg, dtype=np.float64)
    expected = np.asarray(aj.reconstruct(meas, config, params.astype(np.float64)))
    np.testing.assert_allclose(table, expected, rtol=0, atol=atol * float(expected.max()))


def run_phases(phases: list[dict], cwd, timeout: int = 600) -> dict:
    """Run many ``abrdf-jax`` commands in ONE subprocess (JAX imported and functions compiled
    once), phase after phase; returns ``{phase: {job: {"rc", "stderr", "stdout", "seconds"}}}``.

    Each phase is ``{"name", "jobs": [[job, argv], ...], "fsize": bytes or None}``; with
    ``fsize`` the child lowers its soft ``RLIMIT_FSIZE`` to it first (so that phase comes last)
    with ``SIGXFSZ`` ignored, as CPython itself does: a write past the limit then fails with
    ``EFBIG`` instead of killing the process. Every command runs through ``abrdf_jax.cli.main``
    with its own captured stdout and stderr, as ``python -m abrdf_jax.cli ARGV`` would.
    """
    import json

    done = subprocess.run(
        [sys.executable, __file__, json.dumps(phases)],
        cwd=cwd,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


def _phases_child(phases: list[dict]) -> dict:
    import contextlib
    import io
    import json
    import resource
    import signal
    import time

    from abrdf_jax.cli import main

    results, cwd = {}, os.getcwd()
    for phase in phases:
        if phase.get("fsize") is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]
            resource.setrlimit(resource.RLIMIT_FSIZE, (phase["fsize"], hard))
        got = results[phase["name"]] = {}
        for name, argv in phase["jobs"]:
            err, out = io.StringIO(), io.StringIO()
            os.chdir(cwd)
            t0 = time.perf_counter()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                rc = main(list(map(str, argv)))
            got[name] = {"rc": rc, "stderr": err.getvalue(), "stdout": out.getvalue()}
            got[name]["seconds"] = time.perf_counter() - t0
    return json.dumps(results)


if __name__ == "__main__":
    import json

    print(_phases_child(json.loads(sys.argv[1])))
