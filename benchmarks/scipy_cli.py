"""The scipy peer as a command line: what a careful researcher's numpy/scipy script of the method is.

Run: ``python -m benchmarks.scipy_cli IN.csv -o OUT.npz`` (one file) or
``python -m benchmarks.scipy_cli DIR|IN.csv... -o OUT_DIR [--limit N]`` (one ``NAME.npz`` a
measurement file). The reconstruction is the test oracle :func:`tests.scipy_oracle.reconstruct_scipy`
(one copy, shared with :mod:`benchmarks.scipy_peer`); each table is written with ``numpy.savez``
under the key ``abrdf`` (float64, the oracle's own dtype), the key the package's reader accepts.

This module imports neither ``abrdf_jax`` nor JAX, on purpose: it is the peer that
:mod:`benchmarks.cli` times against ``abrdf-jax reconstruct``, so its start-up is numpy and scipy
only. Its reader is a minimal numpy one (PROTOCOL.md's "Measurement file": a header naming
``theta_i,phi_i,theta_v,phi_v,r,g,b`` in any order, one sample a row, degrees); a file it cannot
read is an error on stderr and exit 2, as in the package.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tests.scipy_oracle import MIN_DEGREE, reconstruct_scipy

COLUMNS = ("theta_i", "phi_i", "theta_v", "phi_v", "r", "g", "b")
#: The oracle's arguments for the paper's setting, ``benchmarks.scipy_peer.scipy_kwargs(
#: aj.Config(budget=B), aj.Params.default(config))``; the same for iso102 and aniso204 (the oracle
#: finds the axial slices in the data). The widths and λ are the package's float32 values read
#: back as float64, so that the peer solves exactly what the benchmarks' in-process peer solves;
#: ``tests/test_benchmark_cli.py`` checks that these still equal ``scipy_kwargs``.
PAPER_KWARGS = dict(
    kernel="gaussian",
    widths=(0.44999998807907104,) * 4,
    smoothing=0.009999999776482582,
    degree=None,  # the kernel's minimum degree
    value_space="linear",
    alpha=15.0,
    log_eps=0.01,
    parameterization="onion",
)


class BadInput(Exception):
    """A file or argument the peer cannot use (exit 2)."""


def read_csv(path: Path) -> tuple[np.ndarray, ...]:
    """``theta_i, phi_i, theta_v, phi_v`` (degrees) and ``rgb (n, 3)`` of a measurement CSV file."""
    try:
        with open(path, encoding="utf-8-sig") as f:
            header = [h.strip().lower() for h in f.readline().split(",")]
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise BadInput(f"{path}:1: header lacks column(s) {', '.join(missing)}")
            cols = [header.index(c) for c in COLUMNS]
            data = np.loadtxt(f, delimiter=",", usecols=cols, ndmin=2, dtype=np.float64)
    except OSError as e:
        raise BadInput(f"{path}: cannot read: {e.strerror or e}") from e
    except ValueError as e:  # numpy names the line of the data block (header not counted)
        raise BadInput(f"{path}: {e}") from e
    if data.shape[0] == 0:
        raise BadInput(f"{path}: no data rows after the header")
    if not np.isfinite(data).all():
        row = int(np.argwhere(~np.isfinite(data))[0, 0])
        raise BadInput(f"{path}:{row + 2}: a value is not finite")
    return data[:, 0], data[:, 1], data[:, 2], data[:, 3], data[:, 4:]


def reconstruct_file(path: Path, kwargs: dict) -> np.ndarray:
    """The oracle's ``(81, 81, 3)`` float64 table of one measurement file."""
    ti, pi, tv, pv, rgb = read_csv(path)
    return reconstruct_scipy(ti, pi, tv, pv, rgb, **kwargs)


def inputs(names: list[str], limit: int | None) -> tuple[list[Path], bool]:
    """The measurement files (a folder gives its ``*.csv``, sorted) and whether ``-o`` is a folder."""
    files, folder = [], len(names) > 1
    for name in names:
        p = Path(name)
        if p.is_dir():
            folder = True
            found = sorted(q for q in p.iterdir() if q.suffix.lower() == ".csv" and q.is_file())
            if not found:
                raise BadInput(f"{p}: folder holds no .csv measurement files")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise BadInput(f"{p}: file not found")
    return (files if limit is None else files[:limit]), folder


def _widths(text: str) -> tuple[float, ...]:
    w = tuple(float(x) for x in text.split(","))
    if len(w) == 1:
        w *= 4
    if len(w) != 4 or min(w) <= 0:
        raise argparse.ArgumentTypeError("one or four positive widths, comma separated")
    return w


def parse_args(argv=None) -> argparse.Namespace:
    d = PAPER_KWARGS
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.scipy_cli", description=__doc__.splitlines()[0]
    )
    ap.add_argument("inputs", nargs="+", metavar="MEAS", help="measurement CSV file(s) or folder")
    ap.add_argument("-o", "--output", required=True, type=Path, help="table (.npz) or folder")
    ap.add_argument("--limit", type=int, help="only the first N files (sorted) of the inputs")
    ap.add_argument("--kernel", default=d["kernel"], choices=sorted(MIN_DEGREE))
    ap.add_argument("--widths", type=_widths, default=d["widths"], help="kernel widths")
    ap.add_argument("--smoothing", type=float, default=d["smoothing"], help="λ")
    ap.add_argument("--degree", type=int, default=d["degree"], help="polynomial tail degree")
    ap.add_argument("--value-space", default=d["value_space"], choices=("linear", "log"))
    ap.add_argument("--alpha", type=float, default=d["alpha"], help="slice offset α (degrees)")
    ap.add_argument("--log-eps", type=float, default=d["log_eps"], help="ε of the log values")
    ap.add_argument(
        "--parameterization", default=d["parameterization"], choices=("onion", "onion-hd")
    )
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    kwargs = {k: getattr(args, k) for k in PAPER_KWARGS}
    try:
        if args.limit is not None and args.limit < 1:
            raise BadInput(f"--limit must be at least 1, got {args.limit}")
        files, folder = inputs(args.inputs, args.limit)
        out = args.output
        if folder:
            out.mkdir(parents=True, exist_ok=True)
        elif out.suffix.lower() != ".npz":
            raise BadInput(f"{out}: the peer writes .npz tables; use a .npz name")
        tables = []
        for path in files:  # read and check every file first, as the package does
            tables.append(read_csv(path))
        for path, (ti, pi, tv, pv, rgb) in zip(files, tables):
            table = reconstruct_scipy(ti, pi, tv, pv, rgb, **kwargs)
            np.savez(out / f"{path.stem}.npz" if folder else out, abrdf=table)
    except BadInput as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
