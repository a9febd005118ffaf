"""The inputs of a ``reconstruct`` run: every file read and checked before any work (one bad
file fails the run, naming it, before anything is written), and for a large folder in blocks,
so that the memory a run holds does not grow with the number of files (issue 16, "Load";
``python -m benchmarks.load``)."""

from __future__ import annotations

from .._errors import InputError
from . import _common as common

#: A folder run holds the inputs of at most this many files at once (about 20 KiB each): a larger
#: folder is checked whole first, then read again block by block (docs/stability.md, "Load").
BLOCK = 1024


def read_inputs(files, forced, alpha, before=None, quiet=True, keep=True, warn=True):
    """Read, then plan every input (numpy: no JAX; ``before()`` runs in between); one bad file
    fails the run before any work, naming them all. Unless ``quiet``: a bar over several files,
    a line before and after a large one. ``keep=False`` checks every file and keeps none (the
    first pass of :func:`input_blocks`); ``warn=False`` repeats no warning (its second)."""
    from .. import io

    read, bad, items = [], [], []
    with common.progress(len(files), "read", quiet or len(files) < 2) as bar:
        for f in files:
            try:
                with common.BigFile(f, quiet):
                    samples = io.read_sample_columns(f)
                if keep:
                    read.append((f, samples))
                else:  # planned at once (a bad file's error), then dropped
                    common.plan(samples, forced, alpha, f, warn)
                    if warn:
                        common.warn_negative(f, samples)
            except InputError as e:
                bad.append((f, str(e)))
            bar.update(1)
    if before is not None and not bad:
        before()
    for f, samples in read if not bad else ():
        try:
            items.append(common.plan(samples, forced, alpha, f, warn))
        except InputError as e:
            bad.append((f, str(e)))
    if bad:
        others = ", ".join(str(f) for f, _ in bad[1:4]) + (", ..." if len(bad) > 4 else "")
        more = f" (also bad: {others}; nothing was written)" if len(bad) > 1 else ""
        raise InputError(bad[0][1] + more)
    for item in items if warn else ():
        common.warn_negative(item.path, item.samples)
    return items


def input_blocks(files, targets, forced, alpha, before, quiet):
    """``(items, targets)`` of at most :data:`BLOCK` files each, in order. Every input is read
    and checked before the first block is returned (one bad file fails the run before any
    work); above ``BLOCK`` files the blocks are read again, so memory does not grow with the
    folder."""
    if len(files) <= BLOCK:
        return [(read_inputs(files, forced, alpha, before, quiet), targets)]
    read_inputs(files, forced, alpha, before, quiet, keep=False)
    return (
        (read_inputs(files[i : i + BLOCK], forced, alpha, warn=False), targets[i : i + BLOCK])
        for i in range(0, len(files), BLOCK)
    )
