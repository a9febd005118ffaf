"""How :mod:`benchmarks.cli` runs and times the commands: :class:`Runner` (one child process a
call, through :mod:`benchmarks._timed_child`, in the run's work folder) and :func:`median_run`
(one row of several calls).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = ("-m", "abrdf_jax.cli")
LAUNCHER = ("-m", "benchmarks._timed_child")
CACHE_ENV = "ABRDF_JAX_CACHE_DIR"


class Runner:
    """Runs and times the commands of one benchmark run inside its work folder ``work``."""

    def __init__(self, work: Path, log):
        self.work, self.log = work, log
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = str(REPO) + os.pathsep + self.env.get("PYTHONPATH", "")
        self.env.pop(CACHE_ENV, None)
        # An installed package has its bytecode (pip compiles it on install); a machine that sets
        # PYTHONDONTWRITEBYTECODE=1 (this project's does) would make every child compile the
        # repository's sources again. Both commands read bytecode compiled once here, as a user's
        # installation has it.
        self.env.pop("PYTHONDONTWRITEBYTECODE", None)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "compileall",
                "-q",
                str(REPO / "abrdf_jax"),
                str(REPO / "benchmarks"),
            ],
            env=self.env,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        entry = Path(sys.executable).parent / "abrdf-jax"
        found = entry if entry.exists() else shutil.which("abrdf-jax")
        self.entry_point = [str(found)] if found else [sys.executable, *PACKAGE]

    def shown(self, cmd: list[str], env: dict) -> str:
        """``cmd`` as a reader would type it: ``$WORK`` for the work folder, ``python``."""
        words = [f"{k}={v}" for k, v in env.items()] + cmd
        words = ["python" if w == sys.executable else w for w in words]
        words = [
            "abrdf-jax" if w == self.entry_point[0] and len(self.entry_point) == 1 else w
            for w in words
        ]
        return shlex.join(words).replace(str(self.work), "$WORK").replace(str(REPO) + os.sep, "")

    def once(self, cmd: list[str], env: dict, cwd: Path) -> dict:
        """One call of ``cmd`` through :mod:`benchmarks._timed_child` (its own wall seconds, exit
        code and peak RSS), the tail of its stderr, and the wall time around the launcher."""
        with (
            tempfile.TemporaryFile() as out,
            tempfile.TemporaryFile() as err,
            tempfile.TemporaryDirectory() as tmp,
        ):
            result = Path(tmp) / "result.json"
            launch = [sys.executable, *LAUNCHER, str(result), *cmd]
            if hasattr(
                os, "sync"
            ):  # the earlier runs' writeback lands before, not inside, the call
                os.sync()
            t0 = time.perf_counter()
            proc = subprocess.run(launch, env=self.env | env, cwd=cwd, stdout=out, stderr=err)
            outer = time.perf_counter() - t0
            err.seek(0)
            tail = err.read()[-2000:].decode("utf-8", "replace")
            if proc.returncode != 0 or not result.is_file():  # the launcher itself failed
                return {
                    "seconds": outer,
                    "exit_code": -1,
                    "peak_rss_mib": None,
                    "stderr_tail": tail,
                }
            call = json.loads(result.read_text())
        return call | {"launcher_seconds": outer, "stderr_tail": tail}

    def timed(
        self,
        cmd: list[str],
        *,
        files: int,
        env: dict | None = None,
        cwd: Path | None = None,
        repeats: int = 1,
        expected_exit: int = 0,
        outputs=None,
    ) -> dict:
        """``repeats`` calls of ``cmd``: median seconds, largest RSS, every exit as expected?

        ``outputs`` (a callable returning the count of output files) is checked against
        ``files`` after the calls.
        """
        env = env or {}
        calls = [self.once(cmd, env, cwd or self.work) for _ in range(repeats)]
        bad = [c["exit_code"] for c in calls if c["exit_code"] != expected_exit]
        run = {
            "command": shlex.join([f"{k}={v}" for k, v in env.items()] + cmd),
            "shown": self.shown(cmd, env),
            "files": files,
            **_spread(calls),
            "exit_code": bad[0] if bad else expected_exit,
            "expected_exit": expected_exit,
            "launcher_seconds": [c.get("launcher_seconds") for c in calls],
            "stderr_tail": calls[-1]["stderr_tail"] if bad or expected_exit else "",
        }
        if outputs is not None:
            run["outputs"] = outputs()
        run["ok"] = not bad and run.get("outputs", files) == files
        self.log(
            f"  {run['shown'][:110]:110s} {run['seconds']:8.3f} s  exit {run['exit_code']}"
            f"  {run['peak_rss_mib'] or 0:6.0f} MiB" + ("" if run["ok"] else "  NOT OK")
        )
        return run

    def cache(self, name: str) -> dict:
        """The environment of a fresh, empty cache folder ``$WORK/cache-NAME``."""
        folder = self.work / f"cache-{name}"
        folder.mkdir()
        return {CACHE_ENV: str(folder)}


def count_outputs(folder: Path):
    return lambda: len(list(folder.glob("*.npz"))) if folder.is_dir() else 0


def output_exists(path: Path):
    return lambda: int(path.is_file())


def _spread(calls: list[dict]) -> dict:
    """What a row says of its calls (each with ``seconds`` and ``peak_rss_mib``): the median
    seconds, every call's seconds, how many, the largest RSS."""
    return {
        "seconds": statistics.median(c["seconds"] for c in calls),
        "all_seconds": [c["seconds"] for c in calls],
        "repeats": len(calls),
        "peak_rss_mib": max((c["peak_rss_mib"] or 0.0) for c in calls) or None,
    }


def median_run(calls: list[dict]) -> dict:
    """One row of several timed calls of a command (:meth:`Runner.timed`, one call each): the
    median call's figures, every call's seconds, the largest RSS, every exit as expected."""
    ordered = sorted(calls, key=lambda c: c["seconds"])
    row = dict(ordered[(len(ordered) - 1) // 2]) | _spread(calls)
    row["ok"] = all(c["ok"] for c in calls)
    bad = [c["exit_code"] for c in calls if c["exit_code"] != c["expected_exit"]]
    row["exit_code"] = bad[0] if bad else row["expected_exit"]
    return row
