"""Run one command; write its wall seconds, exit code and peak RSS as JSON (for :mod:`benchmarks.cli`).

Run: ``python -m benchmarks._timed_child RESULT.json CMD [ARG ...]``. The command's output goes
where this process's goes.

Why a process of its own: on Linux a process's peak RSS (``ru_maxrss``) starts from its parent's
RSS at the fork and is carried over ``exec``, so a command forked straight from the benchmark (which
has imported JAX and built the inputs, some 300 MiB) would report at least that much. Forked from
this small process (numpy not imported), the command's own peak is what it reports. The command is
timed here, by ``time.perf_counter`` around ``subprocess.run``, so this process's own start-up is
not counted.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.splitlines()[2], file=sys.stderr)
        return 2
    out, cmd = argv[0], argv[1:]
    t0 = time.perf_counter()
    code = subprocess.run(cmd).returncode
    seconds = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # the one child: no delta needed
    scale = 1024.0**2 if sys.platform == "darwin" else 1024.0  # bytes on macOS, KiB on Linux
    with open(out, "w") as f:
        json.dump({"seconds": seconds, "exit_code": code, "peak_rss_mib": rss / scale}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
