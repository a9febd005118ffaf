"""Bad input at the boundary (issue 5), driven through the command line as a user would.

Every case checks the exit status (2), a one-line message ``abrdf-jax: error: ...`` that names
the file (and line) or argument, that no output file appeared and that an existing output was
left byte for byte. Most cases call ``abrdf_jax.cli.main`` in-process (no JAX start-up per
case); two subprocess tests run the installed entry point end to end.
"""

import errno
import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from abrdf_jax import io
from abrdf_jax.cli import main
from abrdf_jax._errors import InputError
from tests.cli_runner import run_cli

HEADER = "theta_i,phi_i,theta_v,phi_v,r,g,b"
PRECIOUS = b"an existing output that a failed run must not touch"
IS_ROOT = os.name == "posix" and os.geteuid() == 0


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden temp files included) with its content."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def fails(capsys, argv, *names, code=2):
    """Run the CLI in-process; assert a clean one-line failure naming every one of ``names``."""
    status = main([str(a) for a in argv])
    captured = capsys.readouterr()
    err = captured.err
    assert status == code, (argv, status, err)
    lines = [x for x in err.splitlines() if x.strip()]
    errors = [x for x in lines if x.startswith("abrdf-jax: error:")]
    # "replacing FILE": the overwrite policy's notice of a write that then failed (docs/stability.md)
    said = ("abrdf-jax: error:", "abrdf-jax: warning:", "abrdf-jax: replacing ")
    others = [x for x in lines if not x.startswith(said)]
    assert len(errors) == 1 and not others, (argv, err)
    assert "Traceback" not in err
    for name in names:
        assert name in err, (argv, name, err)
    return err


def protocol_rows(budget="iso102", alpha=15.0):
    """PROTOCOL.md slice positions in degrees: rows (θi, φi, θv, φv)."""
    rows = []
    for (ti, tv), n in zip(((30, 30), (30, 75), (75, 30), (75, 75)), (25, 25, 26, 26)):
        t = np.arange(n) * 360.0 / n
        rows += [(ti, (360 - p + alpha) % 360, tv, p) for p in t]  # diagonal
        if budget == "aniso204":
            rows += [(ti, p, tv, (p - alpha) % 360) for p in t]  # axial
    return np.array(rows, dtype=float)


def _samples(rows, rgb=(0.1, 0.2, 0.3)):
    from abrdf_jax._measurements import Samples

    rgb = np.broadcast_to(np.asarray(rgb, float), (len(rows), 3)).copy()
    return Samples(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rgb)


def csv_text(angles, rgb=(0.1, 0.2, 0.3)):
    rgb = np.broadcast_to(np.asarray(rgb, float), (len(angles), 3))
    body = "".join(",".join(repr(float(x)) for x in (*a, *c)) + "\n" for a, c in zip(angles, rgb))
    return HEADER + "\n" + body


def lambertian_table(rho=(0.2, 0.4, 0.6)):
    from abrdf_jax._grid import ubo_grid

    cos_i = np.cos(np.radians(ubo_grid()[0]))
    return (np.asarray(rho) / np.pi * cos_i[:, None, None] * np.ones((81, 81, 1))).astype(
        np.float32
    )


# ---------------------------------------------------------------------------------------------
# Measurement CSV
# ---------------------------------------------------------------------------------------------

_ROW = "30,15,30,0,0.1,0.2,0.3\n"
_RAD = protocol_rows()


CSV_CASES = {
    "missing-column": (
        "theta_i,phi_i,theta_v,r,g,b\n30,15,30,1,1,1\n",
        ":1:",
        "lacks column(s) phi_v",
    ),
    "wrong-header": (
        "ti,pi,tv,pv,red,green,blue\n30,15,30,0,1,1,1\n",
        ":1:",
        "lacks column(s) theta_i",
    ),
    "no-header": (_ROW * 3, ":1:", "looks like data"),
    "text-in-number": (HEADER + "\n" + _ROW + "30,0,30,15,0.1,oops,0.3\n", ":3:", "'oops'"),
    "empty-field": (HEADER + "\n" + _ROW * 4 + "30,0,30,15,0.1,,0.3\n", ":6:", "column 'g'"),
    "short-row": (HEADER + "\n" + _ROW + "30,0,30,15,0.1\n", ":3:", "at least 7 fields"),
    "theta-range": (HEADER + "\n" + _ROW + "30,15,95,0,1,1,1\n", ":3:", "theta_v = 95 degrees"),
    "negative-theta": (HEADER + "\n-3,15,30,0,1,1,1\n", ":2:", "theta_i = -3 degrees"),
    "phi-range": (HEADER + "\n30,800,30,0,1,1,1\n", ":2:", "phi_i = 800 degrees"),
    "nan": (HEADER + "\n" + _ROW + "30,15,30,0,nan,1,1\n", ":3:", "not finite"),
    "inf": (HEADER + "\n30,15,30,0,1,1,-inf\n", ":2:", "not finite"),
    "empty-file": ("", ":1:", "empty file"),
    "blank-lines-only": ("\n \n\n", ":1:", "empty file"),
    "header-only": (HEADER + "\n", "bad.csv", "no data rows"),
    "quote": (HEADER + '\n30,15,30,0,1,1,"1\n', "bad.csv", "malformed CSV"),
    "bare-cr": ((HEADER + "\r" + _ROW.strip() + "\r").encode(), ":1:", "carriage return"),
    "not-utf8": ((HEADER + "\n" + _ROW).encode() + b"30,15,\xff\xfe,0,1,1,1\n", ":3:", "UTF-8"),
    "radians": (csv_text(np.radians(_RAD)), "bad.csv", "look like radians"),
    "radian-azimuths": (
        csv_text(
            np.column_stack(
                [_RAD[:, 0], np.radians(_RAD[:, 1]), _RAD[:, 2], np.radians(_RAD[:, 3])]
            )
        ),
        "bad.csv",
        "azimuths look like radians",
    ),
    # Valid numbers, but no sample on any slice: caught when the slices are grouped.
    "off-slice": (
        csv_text(np.tile([[45.0, 10.0, 60.0, 20.0]], (30, 1))),
        "bad.csv",
        "cannot reconstruct from",
    ),
}


@pytest.mark.parametrize("case", sorted(CSV_CASES))
def test_reconstruct_rejects_bad_csv(tmp_path, capsys, monkeypatch, case):
    content, where, what = CSV_CASES[case]
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "bad.csv"
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    (tmp_path / "rec.npz").write_bytes(PRECIOUS)
    before = snapshot(tmp_path)
    where = where if where.startswith("bad.csv") else "bad.csv" + where
    fails(capsys, ["reconstruct", "bad.csv", "-o", "rec.npz"], where, what)
    assert snapshot(tmp_path) == before


def test_degree_files_are_not_taken_for_radians(tmp_path):
    """The radian rules do not fire on the protocol's own files (iso102 and aniso204)."""
    for budget in ("iso102", "aniso204"):
        p = tmp_path / f"{budget}.csv"
        p.write_text(csv_text(protocol_rows(budget)))
        assert len(io.read_samples_csv(p)) == len(protocol_rows(budget))
    # Small azimuths are fine when they are whole degrees (a fine in-plane scan, say).
    rows = np.array([[30.0, float(k % 7), 75.0, 6.0 - k % 7] for k in range(40)])
    p.write_text(csv_text(rows))
    assert len(io.read_samples_csv(p)) == 40


def test_large_csv_is_streamed_in_bounded_memory(tmp_path):
    """Two million rows: peak memory is the output arrays plus a few MiB.

    The output costs 56 bytes a row (7 float64). Reading the text at once and then converting it
    (the naive way) needs the text (~45 bytes a row) on top of the output; the row-by-row
    ``array.array`` reader this replaced peaked at ~2.4x the output (growth and final copies).
    """
    n_block, repeat = 20_000, 100
    rng = np.random.default_rng(0)
    rows = np.column_stack(
        [
            rng.integers(0, 91, n_block),
            rng.uniform(0, 360, n_block).round(3),
            rng.integers(0, 91, n_block),
            rng.uniform(0, 360, n_block).round(3),
            rng.uniform(-0.01, 1, (n_block, 3)).round(5),
        ]
    )
    block = "".join(",".join(f"{x:g}" for x in r) + "\n" for r in rows)
    p = tmp_path / "big.csv"
    with open(p, "w") as f:
        f.write(HEADER + "\n")
        for _ in range(repeat):
            f.write(block)
    n = n_block * repeat
    output_bytes = n * 7 * 8
    tracemalloc.start()
    try:
        s = io.read_samples_csv(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(s) == n
    np.testing.assert_array_equal(s.theta_i[-n_block:], rows[:, 0])
    np.testing.assert_array_equal(s.rgb[:n_block], rows[:, 4:])
    naive = p.stat().st_size + output_bytes
    assert peak < output_bytes + 32 * 2**20, (peak / 2**20, output_bytes / 2**20)
    assert peak < 0.7 * naive


def test_a_dark_capture_warns_and_reconstructs_zero(tmp_path, capsys, monkeypatch):
    """A capture with no positive value (a dark frame, a capped lens) is reconstructed, but not
    silently: a warning names the file (in a folder, that file only), and the table it
    promises is zero to rounding (the real reconstruction: the log of ``0 + ε`` restored); so
    is a capture with one or two dark channels (those channels zero)."""
    monkeypatch.chdir(tmp_path)
    rows = protocol_rows()
    (tmp_path / "dark.csv").write_text(csv_text(rows, (0.0, 0.0, 0.0)))
    assert main(["reconstruct", "dark.csv", "-o", "dark.npz"]) == 0
    err = capsys.readouterr().err
    assert "warning: dark.csv: every sample is 0 or below (102 samples, max 0)" in err
    assert np.abs(io.read_table(tmp_path / "dark.npz")).max() < 1e-12
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "a.csv").write_text(csv_text(rows))
    rgb = np.zeros((len(rows), 3))
    rgb[3] = -0.001  # below zero is no brighter
    (folder / "b.csv").write_text(csv_text(rows, rgb))
    assert main(["reconstruct", "folder", "-o", "out", "-q"]) == 0
    err = capsys.readouterr().err
    assert "b.csv: every sample is 0 or below (102 samples, max 0)" in err
    assert "a.csv" not in err and "negative" not in err  # one warning: the dark one says it
    # one dark channel (a monochrome camera writing r only): said, and that channel is zero
    (tmp_path / "mono.csv").write_text(csv_text(rows, (0.2, 0.0, 0.0)))
    assert main(["reconstruct", "mono.csv", "-o", "mono.npz"]) == 0
    err = capsys.readouterr().err
    assert "warning: mono.csv: channels g and b are 0 or below in every sample: those" in err
    table = io.read_table(tmp_path / "mono.npz")
    assert np.abs(table[..., 1:]).max() < 1e-12 < table[..., 0].min()
    (tmp_path / "nob.csv").write_text(csv_text(rows, (0.2, 0.1, 0.0)))
    assert main(["reconstruct", "nob.csv", "-o", "nob.npz"]) == 0
    assert (
        "nob.csv: channel b is 0 or below in every sample: that channel" in capsys.readouterr().err
    )


def test_negative_values_warn_and_write_failure_keeps_output(tmp_path, capsys, monkeypatch):
    """Negative samples are kept with a warning; a write that fails half-way leaves no trace.

    The reconstruction itself is replaced by a stub (this is about the boundary, and it saves a
    compilation); the real pipeline clamps its output at 0 (tests/test_pipeline.py).
    """
    from abrdf_jax import _engine

    monkeypatch.chdir(tmp_path)
    seen = []

    def stub(meas, config, params, operator=None, **kw):
        seen.extend(meas)
        yield [0], _T[None], "operator"

    monkeypatch.setattr(_engine, "reconstruct_many", stub)
    rows = protocol_rows()
    rgb = np.tile([0.1, 0.2, 0.3], (len(rows), 1))
    rgb[5, 1] = -0.002  # dark-frame noise
    (tmp_path / "m.csv").write_text(csv_text(rows, rgb))
    assert main(["reconstruct", "m.csv", "-o", "rec.npz"]) == 0
    err = capsys.readouterr().err
    assert (
        "warning: m.csv: 1 of 102 samples have negative values (min -0.002, first in data row 6)"
        in err
    )
    # kept as measured: the reconstruction gets the slices (grouped once), the value unclipped
    assert np.asarray(seen[0].y).min() == np.float32(-0.002)
    assert io.read_table(tmp_path / "rec.npz").tobytes() == _T.tobytes()
    good = (tmp_path / "rec.npz").read_bytes()

    # The disk fills up half-way through the archive: the old file stays, no temp file remains.
    import contextlib

    from abrdf_jax.io import _tables

    real = _tables.atomic_write

    class HalfThenFull:
        def __init__(self, f):
            self.f = f

        def write(self, data):
            self.f.write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

    @contextlib.contextmanager
    def half_then_full(path, *args, **kw):
        with real(path, *args, **kw) as f:
            yield HalfThenFull(f)

    monkeypatch.setattr(_tables, "atomic_write", half_then_full)
    before = snapshot(tmp_path)
    fails(
        capsys, ["reconstruct", "m.csv", "-o", "rec.npz"], "cannot write rec.npz", "No space left"
    )
    assert snapshot(tmp_path) == before and (tmp_path / "rec.npz").read_bytes() == good
    fails(capsys, ["reconstruct", "m.csv", "-o", "new.npz"], "new.npz")
    assert snapshot(tmp_path) == before


def test_sample_write_failure_and_interrupt(tmp_path, capsys, monkeypatch):
    """The CSV writer raises after half the rows (disk full, then Ctrl-C): old output kept.

    The sampling is a stub returning the protocol's 102 positions (no JAX work needed here).
    """
    import abrdf_jax as aj
    import abrdf_jax.io._csv as csv_module

    rows = protocol_rows()
    monkeypatch.setattr(aj, "sample", lambda source, config, params: _samples(rows))
    monkeypatch.chdir(tmp_path)
    io.write_table(tmp_path / "t.npz", lambertian_table())
    (tmp_path / "meas.csv").write_bytes(PRECIOUS)
    real = csv_module._row_text
    for exc, code in (
        (OSError(errno.ENOSPC, "No space left on device"), 2),
        (KeyboardInterrupt(), 130),
    ):
        calls = [0]

        def flaky(x, exc=exc, calls=calls):
            calls[0] += 1
            if calls[0] > 51:  # half of the 102 rows
                raise exc
            return real(x)

        monkeypatch.setattr(csv_module, "_row_text", flaky)
        before = snapshot(tmp_path)
        status = main(["sample", "t.npz", "-o", "meas.csv", "--budget", "iso102"])
        err = capsys.readouterr().err
        assert status == code, err
        assert ("cannot write meas.csv" in err) if code == 2 else ("interrupted" in err)
        assert calls[0] == 51 + 1
        assert snapshot(tmp_path) == before


def test_exr_writer_failure(tmp_path, monkeypatch):
    """A failure inside the EXR library while writing is an InputError naming the file."""
    import abrdf_jax.io._exr as io_module

    p = tmp_path / "t.exr"
    p.write_bytes(PRECIOUS)

    class FakeFile:
        def __init__(self, header, channels):
            pass

        def write(self, f):
            f.write(b"\x76\x2f\x31\x01" + b"\0" * 100)  # EXR magic, then a failure
            raise RuntimeError("simulated encoder failure")

    real = io_module._openexr()
    fake = type(
        "FakeOpenEXR",
        (),
        {
            "File": FakeFile,
            "ZIP_COMPRESSION": real.ZIP_COMPRESSION,
            "NO_COMPRESSION": real.NO_COMPRESSION,
            "scanlineimage": real.scanlineimage,
        },
    )
    monkeypatch.setattr(io_module, "_openexr", lambda: fake)
    with pytest.raises(InputError, match=r"cannot write .*t\.exr: OpenEXR: simulated"):
        io.write_table(p, lambertian_table())
    assert snapshot(tmp_path) == {"t.exr": PRECIOUS}


# ---------------------------------------------------------------------------------------------
# Tables (.npz, .exr) and MERL .binary files
# ---------------------------------------------------------------------------------------------


def _npz(arrays):
    def make(p):
        with open(p, "wb") as f:
            np.savez(f, **arrays)

    return make


def _exr(channels):
    def make(p):
        import OpenEXR

        OpenEXR.File({"type": OpenEXR.scanlineimage}, channels).write(str(p))

    return make


def _npy_bytes(arr):
    import io as pyio

    buf = pyio.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def _damaged(ext, how):
    def make(p):
        io.write_table(p, lambertian_table())
        data = bytearray(p.read_bytes())
        if how == "truncated":
            data = data[: len(data) // 2]
        else:  # flip bytes in the middle of the pixel data
            mid = len(data) // 2
            data[mid : mid + 64] = bytes(255 - b for b in data[mid : mid + 64])
        p.write_bytes(bytes(data))

    return make


_T = lambertian_table()
TABLE_CASES = {
    "shape.npz": (_npz({"abrdf": _T[:80]}), "shape (80, 81, 3)"),
    "stack.npz": (_npz({"abrdf": np.stack([_T, _T])}), "stack of tables"),
    "key.npz": (_npz({"table": _T}), "no array named 'abrdf'"),
    "text.npz": (_npz({"abrdf": np.full((81, 81, 3), "x")}), "dtype <U1"),
    "nan.npz": (_npz({"abrdf": np.where(np.arange(3) == 1, np.nan, _T)}), "NaN or infinite"),
    "bare.npz": (lambda p: p.write_bytes(_npy_bytes(_T)), "bare .npy array"),
    "empty.npz": (lambda p: p.write_bytes(b""), "not an .npz archive"),
    "truncated.npz": (_damaged(".npz", "truncated"), "truncated or corrupt"),
    "corrupt.npz": (_damaged(".npz", "corrupt"), "truncated or corrupt"),
    "channels.exr": (_exr({"R": _T[..., 0].copy(), "G": _T[..., 1].copy()}), "lacks channel(s) B"),
    "small.exr": (_exr({"RGB": _T[:40].copy()}), "81x40"),
    "truncated.exr": (_damaged(".exr", "truncated"), "truncated or corrupt"),
    "corrupt.exr": (_damaged(".exr", "corrupt"), "exr"),
    "random.exr": (lambda p: p.write_bytes(np.random.default_rng(1).bytes(5000)), "OpenEXR"),
}


def test_bad_tables(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    io.write_table(tmp_path / "good.npz", _T)
    for name, (make, what) in TABLE_CASES.items():
        make(tmp_path / name)
    (tmp_path / "meas.csv").write_bytes(PRECIOUS)
    before = snapshot(tmp_path)
    for name, (_, what) in TABLE_CASES.items():
        fails(capsys, ["evaluate", "good.npz", name], name, what)
        fails(capsys, ["evaluate", name, "good.npz"], name)
        fails(capsys, ["sample", name, "-o", "meas.csv"], name)
    for name in ("missing.npz", "missing.exr", "missing.binary"):
        fails(capsys, ["sample", name, "-o", "meas.csv"], name, "not found")
    fails(capsys, ["evaluate", "good.npz", "good.tif"], "good.tif", "unknown table format")
    assert snapshot(tmp_path) == before


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    """A valid MERL file of a Lambertian BRDF (constant per channel), and its BRDF."""
    rho = np.array([0.2, 0.4, 0.6])
    brdf = np.broadcast_to(rho / np.pi, io.MERL_SHAPE).copy()
    p = tmp_path_factory.mktemp("merl") / "lambert.binary"
    io.write_merl_binary(p, brdf)
    return p, rho


def test_merl_sample_and_bad_merl_files(tmp_path, capsys, monkeypatch, merl_file):
    good, rho = merl_file
    data = good.read_bytes()
    monkeypatch.chdir(tmp_path)
    # A valid file: the protocol's samples are rho/pi * cos(theta_i), iso102 by default.
    assert main(["sample", str(good), "-o", "meas.csv"]) == 0
    assert "102 samples (iso102" in capsys.readouterr().out
    s = io.read_samples_csv(tmp_path / "meas.csv")
    expect = rho / np.pi * np.cos(np.radians(s.theta_i))[:, None]
    np.testing.assert_allclose(s.rgb, expect, rtol=1e-6)

    nan = bytearray(data)
    nan[12 + 8 * 777 : 12 + 8 * 778] = np.array([np.nan], "<f8").tobytes()
    cases = {
        "short.binary": (data[:7], "too short for a MERL header"),
        "dims.binary": (
            np.array([90, 90, 360], "<i4").tobytes() + data[12:],
            "(90, 90, 360), expected (90, 90, 180)",
        ),
        "truncated.binary": (data[:-8], f"{len(data) - 8} bytes, expected {len(data)}"),
        "half.binary": (data[: len(data) // 2], "bytes, expected"),
        "extra.binary": (data + b"\0" * 16, f"{len(data) + 16} bytes"),
        "nan.binary": (bytes(nan), "NaN or infinite"),
        "empty.binary": (b"", "too short"),
    }
    for name, (content, _) in cases.items():
        (tmp_path / name).write_bytes(content)
    before = snapshot(tmp_path)
    for name, (_, what) in cases.items():
        fails(capsys, ["sample", name, "-o", "meas.csv"], name, what)
    assert snapshot(tmp_path) == before


# ---------------------------------------------------------------------------------------------
# Unreadable inputs, unwritable or impossible outputs
# ---------------------------------------------------------------------------------------------


def _inputs(folder: Path, merl_path: Path | None = None):
    (folder / "m.csv").write_text(csv_text(protocol_rows()))
    io.write_table(folder / "t.npz", _T)
    io.write_table(folder / "t.exr", _T)
    if merl_path is not None:
        (folder / "m.binary").symlink_to(merl_path)


def _unreadable_runs(capsys):
    fails(capsys, ["reconstruct", "m.csv", "-o", "rec.npz"], "m.csv", "cannot read")
    fails(capsys, ["evaluate", "t.npz", "t.exr"], "t.npz", "cannot read")
    fails(capsys, ["evaluate", "t.exr", "t.exr"], "t.exr", "cannot read")
    fails(capsys, ["sample", "m.binary", "-o", "out.csv"], "m.binary", "cannot read")


def test_unreadable_inputs_simulated(tmp_path, capsys, monkeypatch, merl_file):
    """Permission denied on open (simulated, so it also runs as root)."""
    import abrdf_jax.io._atomic as atomic

    monkeypatch.chdir(tmp_path)
    _inputs(tmp_path, merl_file[0])
    before = snapshot(tmp_path)

    def deny(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(atomic, "open", deny, raising=False)
    _unreadable_runs(capsys)
    assert snapshot(tmp_path) == before


@pytest.mark.skipif(os.name != "posix" or IS_ROOT, reason="needs POSIX permissions, non-root")
def test_unreadable_inputs_chmod(tmp_path, capsys, monkeypatch, merl_file):
    monkeypatch.chdir(tmp_path)
    _inputs(tmp_path)
    (tmp_path / "m.binary").write_bytes(merl_file[0].read_bytes())
    for name in ("m.csv", "t.npz", "t.exr", "m.binary"):
        (tmp_path / name).chmod(0o000)
    try:
        _unreadable_runs(capsys)
    finally:
        for name in ("m.csv", "t.npz", "t.exr", "m.binary"):
            (tmp_path / name).chmod(0o644)
    assert not (tmp_path / "rec.npz").exists() and not (tmp_path / "out.csv").exists()


def _unwritable_runs(capsys):
    fails(capsys, ["reconstruct", "m.csv", "-o", "ro/rec.npz"], "ro/rec.npz", "not writable")
    fails(capsys, ["sample", "t.npz", "-o", "ro/meas.csv"], "ro/meas.csv", "not writable")
    fails(capsys, ["reconstruct", "m.csv", "m.csv", "-o", "ro/out"], "ro/out", "not writable")
    fails(capsys, ["reconstruct", "m.csv", "m.csv", "-o", "ro"], "ro", "not writable")


def test_unwritable_output_simulated(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _inputs(tmp_path)
    (tmp_path / "ro").mkdir()
    before = snapshot(tmp_path)
    real = os.access

    def access(path, mode, **kwargs):
        if Path(path).resolve() == (tmp_path / "ro").resolve() and mode & os.W_OK:
            return False
        return real(path, mode, **kwargs)

    monkeypatch.setattr(os, "access", access)
    _unwritable_runs(capsys)
    assert snapshot(tmp_path) == before


@pytest.mark.skipif(os.name != "posix" or IS_ROOT, reason="needs POSIX permissions, non-root")
def test_unwritable_output_chmod(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _inputs(tmp_path)
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro").chmod(0o555)
    try:
        _unwritable_runs(capsys)
        assert list((tmp_path / "ro").iterdir()) == []
    finally:
        (tmp_path / "ro").chmod(0o755)


def test_impossible_outputs(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _inputs(tmp_path)
    (tmp_path / "adir.npz").mkdir()
    before = snapshot(tmp_path)
    fails(
        capsys,
        ["reconstruct", "m.csv", "-o", "missing/rec.npz"],
        "missing/rec.npz",
        "does not exist",
    )
    fails(
        capsys,
        ["reconstruct", "m.csv", "m.csv", "-o", "missing/out"],
        "missing/out",
        "does not exist",
    )
    fails(
        capsys, ["sample", "t.npz", "-o", "missing/meas.csv"], "missing/meas.csv", "does not exist"
    )
    fails(capsys, ["reconstruct", "m.csv", "-o", "rec"], "rec", "unknown table extension '(none)'")
    fails(capsys, ["reconstruct", "m.csv", "-o", "rec.hdr"], "rec.hdr", "unknown table extension")
    fails(
        capsys, ["sample", "t.npz", "-o", "meas.tsv"], "meas.tsv", "unknown measurement extension"
    )
    fails(capsys, ["reconstruct", "m.csv", "-o", "adir.npz"], "adir.npz", "is a folder")
    fails(capsys, ["reconstruct", "m.csv", "m.csv", "-o", "t.npz"], "t.npz", "output folder")
    assert snapshot(tmp_path) == before


# ---------------------------------------------------------------------------------------------
# End to end: the installed command in a subprocess
# ---------------------------------------------------------------------------------------------


def test_batch_with_bad_inputs_writes_nothing(tmp_path):
    """Several inputs, two bad: every input is read and checked before any work; the message
    names the first bad file and line and the other bad file; an existing output folder keeps
    its content and gets no new file."""
    good = csv_text(protocol_rows())
    (tmp_path / "a.csv").write_text(good)
    (tmp_path / "b.csv").write_text(good.replace("\n30.0,", "\n30.0,x", 1))  # line 2
    (tmp_path / "c.csv").write_text(good)
    (tmp_path / "d.csv").write_text("")
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.npz").write_bytes(PRECIOUS)
    before = snapshot(tmp_path)
    proc = run_cli(
        "reconstruct", "a.csv", "b.csv", "c.csv", "d.csv", "-o", "out", "-q", cwd=tmp_path
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("abrdf-jax: error: b.csv:2:"), (
        proc.stderr
    )
    assert "also bad: d.csv; nothing was written" in proc.stderr
    assert snapshot(tmp_path) == before


def test_folder_input_with_bad_files_creates_no_output_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.csv").write_text(csv_text(protocol_rows()))
    (tmp_path / "in" / "b.csv").write_text(HEADER + "\n30,15,30,0,1,1\n")
    before = snapshot(tmp_path)
    fails(capsys, ["reconstruct", "in", "-o", "new"], "b.csv:2:", "at least 7 fields")
    assert snapshot(tmp_path) == before and not (tmp_path / "new").exists()


def test_corrupt_merl_file_in_subprocess(tmp_path, merl_file):
    data = merl_file[0].read_bytes()
    (tmp_path / "cut.binary").write_bytes(data[: len(data) - 1000])
    (tmp_path / "meas.csv").write_bytes(PRECIOUS)
    proc = run_cli("sample", "cut.binary", "-o", "meas.csv", cwd=tmp_path)
    assert proc.returncode == 2
    assert (
        proc.stderr.startswith("abrdf-jax: error: cut.binary:") and "bytes, expected" in proc.stderr
    )
    assert proc.stderr.count("\n") == 1
    assert snapshot(tmp_path) == {"cut.binary": data[: len(data) - 1000], "meas.csv": PRECIOUS}


# ---------------------------------------------------------------------------------------------
# What of a capture is used (issue 12, "say what was used")
# ---------------------------------------------------------------------------------------------


def test_capture_too_small_is_refused_with_the_minimum(tmp_path, capsys):
    """Three samples on one pair cannot support a reconstruction: exit 2, the minimum, no file."""
    p = tmp_path / "three.csv"
    p.write_text(csv_text(protocol_rows()[:3]))
    before = snapshot(tmp_path)
    fails(
        capsys,
        ["reconstruct", p, "-o", tmp_path / "t.npz"],
        "three.csv",
        "at least 2 elevation pairs",
    )
    assert snapshot(tmp_path) == before


def test_missing_pairs_and_off_slice_samples_are_reported(tmp_path, capsys):
    """A capture without two of its pairs and with stray samples: reconstructed, with warnings,
    and the model record says what was used and what was left out."""
    import json

    rows = protocol_rows()
    half = rows[rows[:, 0] == 30]  # the pairs 30/30 and 30/75 only
    stray = np.array([[30.0, 100.0, 30.0, 7.0], [30.0, 200.0, 75.0, 3.0]])  # on no slice
    p = tmp_path / "half.csv"
    p.write_text(csv_text(np.concatenate([half, stray])))
    out = tmp_path / "h.npz"
    assert main(["reconstruct", str(p), "-o", str(out), "--model", "iso"]) == 0
    err = capsys.readouterr().err
    assert "no sample at elevation pair(s) [[75.0, 30.0], [75.0, 75.0]]" in err
    assert "2 of 52 samples lie on no slice" in err
    used = json.loads((tmp_path / "h.model.json").read_text())["measurement"]
    assert used["pairs"] == [[30.0, 30.0], [30.0, 75.0]]
    assert used["dropped_pairs"] == [[75.0, 30.0], [75.0, 75.0]]
    assert (used["n_samples"], used["n_used"], used["n_off_slice"]) == (52, 50, 2)
    assert [c["diagonal"] for c in used["samples_per_slice"]] == [25, 25]
    assert out.exists()
