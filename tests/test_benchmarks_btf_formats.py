"""The store-format row of ``python -m benchmarks.btf`` (benchmarks/_btf_formats.py): each format
run once (a row already run is reused and its store kept), the bytes on disk counted over every
file of the store, the stores it made removed, one table line per format. No speed is checked:
the child runs are stand-ins."""

from benchmarks import _btf_formats


def _fake_child(sizes):
    def run(meas, out, fmt="npy"):
        out.mkdir()
        (out / "a").write_bytes(b"x" * sizes[fmt])
        (out / "sub").mkdir()
        (out / "sub" / "b").write_bytes(b"y")
        warm = dict(seconds=2.0, write_seconds=1.0)
        return dict(cold=dict(seconds=5.0), warm=warm, peak_rss_bytes=2**30)

    return run


def test_both_formats_measured_and_their_stores_removed(tmp_path):
    sizes = dict(npy=1000, zarr=3000)
    run = _fake_child(sizes)
    kept = tmp_path / "rec"
    known = {"npy": (run(None, kept, "npy"), kept)}
    calls = []

    def counting(meas, out, fmt="npy"):
        calls.append(fmt)
        return run(meas, out, fmt)

    fc = _btf_formats.compare(tmp_path, tmp_path / "meas", 4, counting, known)
    assert calls == ["zarr"]
    assert kept.is_dir() and not (tmp_path / "formats-zarr4").exists()
    for fmt, r in fc["rows"].items():
        assert (r["files"], r["bytes"]) == (2, sizes[fmt] + 1)
        assert r["texels_per_second_warm"] == 16 / 2.0 and r["peak_rss_gib"] == 1.0
    lines = _btf_formats.markdown_rows(fc, 1024)
    assert [ln.split("|")[1].strip() for ln in lines[2:4]] == ["npy", "zarr"]
    # the reused row is the headline's round, said below the table (only that one)
    assert lines[4:] == [
        "",
        "Each row is one fresh process; npy: the headline's round of median cold time, cold and "
        "warm from that one process.",
    ]
    assert "4², float16, chunks of 1024" in lines[0]
