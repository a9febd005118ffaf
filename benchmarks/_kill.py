"""The SIGKILL harness of issue 16 ("killed at any point"), shared by ``tests/test_kill.py`` (a
few kill points per command) and ``python -m benchmarks.faults`` (20 or more).

A :class:`Command` is a CLI run (``python -m abrdf_jax.cli ARGS``) with the outputs it writes, a
check of what a killed run leaves (every output absent, or complete and valid) and a digest of
the finished result. :func:`kill_points` runs it once uninterrupted (the reference; a second,
warm run times the kill window), then for each seeded kill point starts it in a fresh output
folder, kills it with SIGKILL at a moment drawn between its start and its expected end (the
median of the latest uninterrupted warm runs: the machine's load changes), or
(every other point) as soon as a drawn number of its pieces (tables, chunks) is on disk, checks
what the killed run left, reruns
it to completion (``Command.rerun``: with ``--resume`` where the command has it) and checks that
the result equals the reference bit for bit, that no temporary file
(:func:`abrdf_jax.io.is_temp`) nor lock file (``.NAME.lock``) is left, and that
the record (model record, store manifest, parameter file) is valid.

Every wait is bounded (``timeout``); a run that fails says so with the child's output.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from abrdf_jax.io import is_temp

REPO = Path(__file__).resolve().parents[1]
#: The longest one run may take (seconds) before the harness gives up on it.
TIMEOUT = 600.0
#: How often the harness looks at the clock and the output while it waits to kill.
POLL = 0.002


@dataclass(frozen=True)
class Command:
    """One command under test.

    Attributes:
        name: how the table names it (``"reconstruct DIR"``).
        argv: ``argv(out)``: the arguments after ``abrdf-jax`` that write into folder ``out``.
        outputs: ``outputs(out)``: every output path the command writes (files or folders), with
            the files beside them (a model record) that it writes under the same lock.
        check: ``check(out)``: problems with the outputs present in ``out`` (absent ones are
            fine; a present one must be complete and valid): a list of messages.
        digest: ``digest(out)``: the finished result as ``{name: bytes}``, compared bit for bit
            with the reference's (what is meant to vary, a date or a duration, left out).
        pieces: ``pieces(out)``: how many pieces (tables, chunks) are on disk: where a kill fell.
        rerun: extra arguments of the rerun after a kill (``("--resume",)``).
        kept: ``kept(output)``: how many pieces the rerun says it kept from the killed runs
            (from its printed summary), so a report shows that resuming was exercised.
    """

    name: str
    argv: Callable[[Path], list]
    outputs: Callable[[Path], list[Path]]
    check: Callable[[Path], list[str]]
    digest: Callable[[Path], dict[str, bytes]]
    pieces: Callable[[Path], int]
    rerun: tuple = ()
    kept: Callable[[str], int] = lambda said: 0


@dataclass
class Point:
    """One kill point and what came of it."""

    index: int
    at: float  # seconds after the start at which SIGKILL is sent at the latest (the draw)
    target: int = 0  # > 0: SIGKILL as soon as this many pieces are on disk (a progress point)
    sent: float | None = None  # seconds after the start at which SIGKILL was sent
    ran: float = 0.0  # seconds from the start to the end of the run (killed or not)
    killed: bool = False  # False: the run ended by itself before the moment came
    pieces: int = 0  # pieces on disk after the kill
    temps: int = 0  # temporary files the killed run left
    lock: bool = False  # its lock file left
    rerun_s: float = 0.0
    kept: int | None = None  # pieces the rerun to completion kept (its own summary)
    problems: list[str] = field(default_factory=list)


@dataclass
class Report:
    """The outcome of :func:`kill_points` for one command."""

    command: str
    seed: int
    reference_s: float  # the uninterrupted (cold) run
    warm_s: float  # the second uninterrupted run: the kill window
    first_piece_s: float | None  # when the warm run's first piece appeared
    total_pieces: int
    points: list[Point]
    cache_temps: int = 0  # temporary files left in the cache folder (removed after an hour)
    problems: list[str] = field(default_factory=list)  # of the reference runs themselves

    @property
    def failed(self) -> list[str]:
        out = list(self.problems)
        for p in self.points:
            when = f"at piece {p.target}" if p.target else f"at {p.at:.3f} s"
            out += [f"kill point {p.index} ({when}): {m}" for m in p.problems]
        return out


def _env(cache: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["ABRDF_JAX_CACHE_DIR"] = str(cache)
    env.pop("ABRDF_JAX_NO_CACHE", None)
    return env


def _start(args, cwd: Path, cache: Path, log: Path) -> subprocess.Popen:
    """``abrdf-jax ARGS`` in ``cwd``, its output to ``log`` (a file: a full pipe would stall it)."""
    with open(log, "w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "abrdf_jax.cli", *map(str, args)],
            cwd=cwd,
            env=_env(cache),
            stdout=f,
            stderr=subprocess.STDOUT,
        )


def _tail(log: Path, n: int = 1500) -> str:
    try:
        return log.read_text(errors="replace")[-n:]
    except OSError:
        return ""


def _complete(args, cwd: Path, cache: Path, log: Path, timeout: float) -> tuple[int, float, str]:
    """Run ``abrdf-jax ARGS`` to its end: ``(exit status, seconds, output tail)``."""
    t0 = time.perf_counter()
    child = _start(args, cwd, cache, log)
    try:
        rc = child.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()
        rc = -1
    return rc, time.perf_counter() - t0, _tail(log)


def _timed(cmd: Command, out: Path, cwd: Path, cache: Path, log: Path, timeout: float):
    """An uninterrupted run, watched: ``(exit status, seconds, first piece at, output tail)``."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    child = _start(cmd.argv(out), cwd, cache, log)
    first = None
    try:
        while child.poll() is None:
            if first is None and cmd.pieces(out) > 0:
                first = time.perf_counter() - t0
            if time.perf_counter() - t0 > timeout:
                child.kill()
                break
            time.sleep(0.01)
        rc = child.wait()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    return rc, time.perf_counter() - t0, first, _tail(log)


def leftovers(out: Path) -> tuple[list[str], list[str]]:
    """The temporary files (:func:`abrdf_jax.io.is_temp`) and lock files under ``out``."""
    temps, locks = [], []
    for root, _, names in os.walk(out):
        for n in names:
            p = str(Path(root, n).relative_to(out))
            if n.startswith(".") and n.endswith(".lock"):
                locks.append(p)
            elif is_temp(n) or n.endswith(".partial"):
                temps.append(p)
    return sorted(temps), sorted(locks)


def _compare(got: dict[str, bytes], want: dict[str, bytes]) -> list[str]:
    problems = []
    if got.keys() != want.keys():
        missing, extra = sorted(want.keys() - got.keys()), sorted(got.keys() - want.keys())
        problems.append(f"result parts differ: missing {missing[:5]}, extra {extra[:5]}")
    differ = sorted(k for k in got.keys() & want.keys() if got[k] != want[k])
    if differ:
        problems.append(f"{len(differ)} part(s) not bit-identical to the reference: {differ[:5]}")
    return problems


def kill_points(
    cmd: Command,
    root: Path,
    n: int,
    seed: int,
    *,
    chain: bool = False,
    timeout: float = TIMEOUT,
    say: Callable[[str], None] | None = None,
) -> Report:
    """Kill ``cmd`` at ``n`` seeded moments, rerun it after each, and check (module docstring).

    Args:
        cmd: the command.
        root: an empty working folder (inputs the command reads live elsewhere).
        n: the number of kill points.
        seed: of the kill moments.
        chain: kill the reruns too: each point kills the rerun of the one before in the same
            output folder (an output interrupted again and again), and only the last run of a
            chain goes to completion; a chain ends where a run ends before its kill. Costs one
            complete rerun per chain instead of one per point (the CI test); ``False``: every
            point in a fresh output folder (the benchmark).
        timeout: the longest any one run may take.
        say: called with one line per kill point (progress), if given.

    Returns:
        The :class:`Report`; ``report.failed`` lists every problem found.
    """
    root = Path(root)
    cache = root / "cache"
    rc, ref_s, _, tail = _timed(cmd, root / "ref", root, cache, root / "ref.log", timeout)
    report = Report(cmd.name, seed, ref_s, 0.0, None, 0, [])
    if rc != 0:
        report.problems.append(f"the reference run failed (rc {rc}): {tail}")
        return report
    want = cmd.digest(root / "ref")
    report.total_pieces = cmd.pieces(root / "ref")
    report.problems += [f"reference: {m}" for m in cmd.check(root / "ref")]
    # the second run: warm caches, as every killed run; it times the kill window
    warm = root / "warm"
    rc, warm_s, first, tail = _timed(cmd, warm, root, cache, root / "warm.log", timeout)
    report.warm_s, report.first_piece_s = warm_s, first
    if rc != 0:
        report.problems.append(f"the second uninterrupted run failed (rc {rc}): {tail}")
        return report
    report.problems += [f"second run: {m}" for m in _compare(cmd.digest(warm), want)]
    rng = np.random.default_rng(seed)
    lo = (first if first is not None else 0.0) / warm_s  # where outputs start, as a fraction
    out, fresh, whole = None, True, [warm_s]  # whole: durations of uninterrupted warm runs
    for k in range(n):
        # half the points at a time anywhere in the run; half at a progress point: as soon as
        # a drawn number of pieces is on disk (times would mostly miss the short window where
        # a run's outputs appear), or, for a single output, at a time inside that window. The
        # run's length follows the machine's load: the latest uninterrupted runs' median.
        span = float(np.median(whole[-5:]))
        at = span * float(rng.uniform(0.0, 1.0) if k % 2 == 0 else rng.uniform(lo, 1.0))
        target = 0
        if k % 2 and report.total_pieces > 1:
            at, target = timeout, int(rng.integers(1, report.total_pieces))
        if fresh:
            out = _fresh(root / f"k{k:03d}")
        extra = () if fresh else cmd.rerun
        p = _kill_once(cmd, out, root, cache, Point(k, at, target), extra, timeout)
        report.points.append(p)
        if fresh and not p.killed and not p.problems:
            whole.append(p.ran)
        last = k == n - 1 or not chain or not p.killed
        if last and not p.problems:
            p.rerun_s, p.kept, problems = _finish(cmd, out, root, cache, k, want, timeout)
            p.problems += problems
            if p.pieces == 0 and not problems:  # nothing to keep: the rerun was a whole run
                whole.append(p.rerun_s)
        fresh = last
        if say is not None:
            state = "killed" if p.killed else "ended first"
            when = f"at piece {target}" if target else f"at {at:.2f} s"
            when += f" (sent at {p.sent:.2f} s)" if p.sent is not None else ""
            say(
                f"{cmd.name}: point {k + 1}/{n} {when}: {state}, {p.pieces} piece(s) on "
                f"disk, {p.temps} temp(s){', lock' if p.lock else ''}"
                + (f"; rerun {p.rerun_s:.1f} s, kept {p.kept}" if last else "; killed again next")
                + (f"; PROBLEMS: {p.problems}" if p.problems else "")
            )
    report.cache_temps = len(leftovers(cache)[0]) if cache.exists() else 0
    return report


def _fresh(out: Path) -> Path:
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    return out


def _kill_once(cmd, out, root, cache, p: Point, extra, timeout) -> Point:
    """Run ``cmd`` (with ``extra`` arguments) into ``out`` and SIGKILL it ``p.at`` seconds after
    its start, or once ``p.target`` pieces are on disk; check what it left."""
    log = root / f"k{p.index:03d}.log"
    need = cmd.pieces(out) + p.target  # pieces a chained rerun finds are not its progress
    t0 = time.perf_counter()
    child = _start([*cmd.argv(out), *extra], root, cache, log)
    try:
        while child.poll() is None and time.perf_counter() - t0 < p.at:
            if p.target and cmd.pieces(out) >= need:
                break
            time.sleep(POLL)
        if child.poll() is None:
            child.send_signal(signal.SIGKILL)
            p.sent = time.perf_counter() - t0
        rc = child.wait(timeout=timeout)
        p.ran = time.perf_counter() - t0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    p.killed = rc == -signal.SIGKILL
    if not p.killed and rc != 0:
        p.problems.append(f"the run to be killed failed by itself (rc {rc}): {_tail(log)}")
        return p
    # what the kill left: each output absent, or complete and valid
    p.pieces = cmd.pieces(out)
    temps, locks = leftovers(out)
    p.temps, p.lock = len(temps), bool(locks)
    p.problems += [f"after the kill: {m}" for m in cmd.check(out)]
    return p


def _finish(cmd, out, root, cache, k, want, timeout) -> tuple[float, int, list[str]]:
    """The rerun to completion: the same result as the reference, nothing left over."""
    rc, seconds, tail = _complete(
        [*cmd.argv(out), *cmd.rerun], root, cache, root / f"k{k:03d}.rerun.log", timeout
    )
    if rc != 0:
        return seconds, 0, [f"the rerun failed (rc {rc}): {tail}"]
    problems = [f"after the rerun: {m}" for m in cmd.check(out)]
    problems += _compare(cmd.digest(out), want)
    temps, locks = leftovers(out)
    if temps or locks:
        problems.append(f"left after the rerun: {temps + locks}")
    problems += [
        f"after the rerun: {p.name} is missing" for p in cmd.outputs(out) if not p.exists()
    ]
    return seconds, cmd.kept(tail), problems
