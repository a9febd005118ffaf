"""What a long run shows while it works (issue 16, "Load"): a ``tqdm`` bar over the files of a
folder run (reading, choosing models, reconstructing); for one file, a line before reading a
large one and a line for each stage (choosing the model, reconstructing) still running after a
few seconds (a large capture, or the first run's compile), so no long stage is silent while a
quick run prints nothing more. ``-q`` turns them off. Used through :mod:`abrdf_jax.cli._common`.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time

#: A measurement file this large (bytes) is announced before it is read (about 200,000 rows;
#: reading one takes a second or more).
BIG_FILE_BYTES = 8 << 20
#: A stage of one file still running after this many seconds says so on stderr.
SLOW_STAGE_S = 5.0


#: The bar over a folder's files being read shows only after this many seconds (a quick read,
#: or a bad file found at once, prints no bar).
READ_BAR_DELAY = 1.0


class _Silent:
    """The bar of a quiet run: the calls of a ``tqdm`` bar that the command line makes, doing
    nothing, and without importing ``tqdm`` (its import time: ``python -X importtime -c "import
    tqdm"``)."""

    def __enter__(self):
        return self

    def __exit__(self, *_):
        return False

    def update(self, n: int = 1) -> None:
        pass

    def set_description(self, desc: str) -> None:
        pass

    def close(self) -> None:
        pass


def progress(total: int, desc: str, disable: bool, delay: float = 0.0):
    """A ``tqdm`` progress bar over files, on stderr (shown after ``delay`` seconds); with
    ``disable`` one that shows nothing."""
    if disable:
        return _Silent()
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit="file",
        file=sys.stderr,
        disable=disable,
        dynamic_ncols=True,
        delay=delay,
    )


def _say(message: str) -> None:
    print(f"abrdf-jax: {message}", file=sys.stderr, flush=True)


class BigFile:
    """Announce the reading of one large file (``with BigFile(path, quiet): read(path)``)."""

    def __init__(self, path, quiet: bool):
        try:
            size = os.path.getsize(path)
        except OSError:  # the reader reports it
            size = 0
        self.path, self.on = path, not quiet and size >= BIG_FILE_BYTES
        if self.on:
            _say(f"reading {path} ({size / 2**20:.1f} MiB) ...")
            self.t0 = time.perf_counter()

    def __enter__(self):
        return self

    def __exit__(self, kind, *_):
        if self.on and kind is None:
            _say(f"read {self.path} in {time.perf_counter() - self.t0:.1f} s")


@contextlib.contextmanager
def stage(item, what: str, quiet: bool):
    """``with stage(item, "choosing the model", quiet):`` one line if the block still runs after
    :data:`SLOW_STAGE_S` seconds, and one when it ends; nothing for a quick block."""
    if quiet:
        yield
        return
    t0, said = time.perf_counter(), []

    def slow():
        said.append(True)
        _say(f"{item.path}: {what} ({len(item.samples)} samples) ...")

    timer = threading.Timer(SLOW_STAGE_S, slow)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        if said:
            _say(f"{item.path}: {what}: done in {time.perf_counter() - t0:.1f} s")
