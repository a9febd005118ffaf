"""One command per file, ``P`` at a time (for :mod:`benchmarks.cli`): what a shell loop with
``xargs -P P`` or a job array does with a command line that takes one file.

Run: ``python -m benchmarks._parallel_calls P N IN_DIR OUT_DIR CMD ...``: the first ``N`` CSV
files of ``IN_DIR`` (sorted), each through ``CMD`` with ``{in}`` replaced by the file and
``{out}`` by ``OUT_DIR/STEM.npz``, ``P`` processes at a time; the exit status is the first
non-zero one of the calls (0 if every call succeeded). Output of the calls is discarded.
"""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def commands(n: int, in_dir: Path, out_dir: Path, template: list[str]) -> list[list[str]]:
    """Each of the first ``n`` CSV files of ``in_dir`` as ``template`` with ``{in}``/``{out}``."""
    files = sorted(in_dir.glob("*.csv"))[:n]
    return [
        [
            w.replace("{in}", str(f)).replace("{out}", str(out_dir / f"{f.stem}.npz"))
            for w in template
        ]
        for f in files
    ]


def run(cmds: list[list[str]], parallel: int) -> int:
    """Every command, ``parallel`` at a time; the first non-zero exit status, else 0."""

    def one(cmd):
        return subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode

    with ThreadPoolExecutor(parallel) as pool:
        codes = list(pool.map(one, cmds))
    return next((c for c in codes if c), 0)


def main(argv: list[str]) -> int:
    if len(argv) < 5:
        print(__doc__.splitlines()[2], file=sys.stderr)
        return 2
    parallel, n, in_dir, out_dir, template = int(argv[0]), int(argv[1]), argv[2], argv[3], argv[4:]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return run(commands(n, Path(in_dir), out, template), parallel)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
