"""The two store formats side by side (issue 15), part of ``python -m benchmarks.btf``.

The largest BTF of the run reconstructed into the ``.npy`` chunk store and into the zarr v3
group (``reconstruct_btf(format=...)``, what ``abrdf-jax btf reconstruct --format`` runs) with
the same settings: float16 store, chunks of 1024 texels, one fresh process per format (a cold
call, then a warm one into a new folder). Per format: wall time cold and warm, the writers' busy
seconds (both formats fsync every chunk before its name appears), peak resident memory, and the
store on disk (files, bytes as stored, bytes allocated). ``--formats`` runs only this part and
writes ``btf_formats{,_quick}.{json,md}``; a full run puts it into ``btf.json``/``btf.md``.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from ._loadavg import load_average

FORMATS = ("npy", "zarr")


def disk_usage(folder: Path) -> dict:
    """Files under ``folder``, their bytes (``st_size``) and the bytes allocated for them."""
    files = size = allocated = 0
    for root, _, names in os.walk(folder):
        for n in names:
            st = os.stat(os.path.join(root, n))
            files, size, allocated = files + 1, size + st.st_size, allocated + st.st_blocks * 512
    return dict(files=files, bytes=size, allocated_bytes=allocated)


def compare(work: Path, meas: Path, size: int, run_child, known=None) -> dict:
    """Each format's row at ``size`` texels per side; ``known``: ``{format: (child result,
    store folder)}`` already run (kept), the others are run here and their stores removed."""
    known = known or {}
    rows = {}
    for fmt in FORMATS:
        if fmt in known:
            r, out = known[fmt]
        else:
            out = work / f"formats-{fmt}{size}"
            r = run_child(meas, out, fmt=fmt)
        rows[fmt] = dict(
            seconds_cold=r["cold"]["seconds"],
            seconds_warm=r["warm"]["seconds"],
            write_seconds_warm=r["warm"]["write_seconds"],
            texels_per_second_warm=size * size / r["warm"]["seconds"],
            peak_rss_gib=r["peak_rss_bytes"] / 2**30,
            from_headline=fmt in known,
            **disk_usage(out),
        )
        if fmt not in known:
            shutil.rmtree(out, ignore_errors=True)
        print(
            f"{fmt} store, {size}x{size}: cold {r['cold']['seconds']:.1f} s, warm "
            f"{r['warm']['seconds']:.1f} s, {rows[fmt]['bytes'] / 2**30:.2f} GiB in "
            f"{rows[fmt]['files']} files",
            flush=True,
        )
    return dict(size=size, texels=size * size, store_dtype="float16", rows=rows)


def markdown_rows(fc: dict, chunk: int) -> list[str]:
    """The table of one :func:`compare` result."""
    lines = [
        f"| store format ({fc['size']}², {fc['store_dtype']}, chunks of {chunk}, same settings) "
        "| cold | warm | write (busy, warm) | texels/s (warm) | on disk | files | peak RSS |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for fmt, r in fc["rows"].items():
        lines.append(
            f"| {fmt} | {r['seconds_cold']:.1f} s | {r['seconds_warm']:.1f} s | "
            f"{r['write_seconds_warm']:.1f} s | {r['texels_per_second_warm']:.0f} | "
            f"{r['bytes'] / 2**20:.1f} MiB ({r['allocated_bytes'] / 2**20:.1f} MiB allocated) | "
            f"{r['files']} | {r['peak_rss_gib']:.2f} GiB |"
        )
    shared = [fmt for fmt, r in fc["rows"].items() if r.get("from_headline")]
    if shared:  # its warm run is that round's own, not the headline's median of the rounds
        lines += [
            "",
            f"Each row is one fresh process; {', '.join(shared)}: the headline's round of median "
            "cold time, cold and warm from that one process.",
        ]
    return lines


def markdown(out: dict) -> str:
    """``btf_formats.md``: the ``--formats`` run alone."""
    m = out["machine"]
    cmd = "python -m benchmarks.btf --formats" + (" --quick" if out["quick"] else "")
    return "\n".join(
        [
            f"# BTF store formats{' (quick)' if out['quick'] else ''}",
            "",
            f"`{cmd}`, {m['date']}, {m['platform']}, {m['cpu_count']} CPU cores, JAX {m['jax']} "
            f"on {', '.join(m['jax_devices'])}, float32 compute, seed {out['seed']}; load "
            f"average (1 min) {out['load_average_start'][0]:.1f} at the start, "
            f"{out['load_average_end'][0]:.1f} at the end. {out['note']}",
            "",
            *markdown_rows(out["store_formats"], out["chunk"]),
            "",
            "Each format in a fresh process: cold (operator build and compilation included), then "
            "warm into a new folder. Both write each chunk to a temporary file, fsync it and "
            "rename it onto its name; zarr chunks carry a crc32c codec, no compression.",
            "",
        ]
    )


def write(out: dict, suffix: str, results: Path) -> int:
    """Write the ``--formats`` run's ``btf_formats{suffix}.json`` and ``.md``."""
    from ._common import write_json

    out["load_average_end"] = load_average()
    path = write_json(f"btf_formats{suffix}.json", out)
    (results / f"btf_formats{suffix}.md").write_text(markdown(out), encoding="utf-8")
    print(f"{path}: written")
    return 0
