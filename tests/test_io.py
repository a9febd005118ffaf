"""File I/O: atomic writes, measurement CSV, ABRDF tables (.npz, .exr), MERL .binary files."""

import os
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from abrdf_jax._errors import InputError
from abrdf_jax._grid import to_vector, vectors_from_half_diff
from abrdf_jax._measurements import Samples
from abrdf_jax.io import (
    MERL_SCALE,
    MERL_SHAPE,
    atomic_write,
    merl_lookup,
    read_merl_binary,
    read_samples_csv,
    read_table,
    write_merl_binary,
    write_samples_csv,
    write_table,
)

HEADER = "theta_i,phi_i,theta_v,phi_v,r,g,b"


def _raises(path, line=None, match=None):
    """pytest.raises(InputError) whose message names the file (and line) and matches ``match``."""
    pattern = re.escape(str(path)) + (f":{line}:" if line is not None else "")
    if match:
        pattern += ".*" + match
    return pytest.raises(InputError, match=pattern)


def _random_samples(rng, n):
    return Samples(
        rng.uniform(0, 90, n),
        rng.uniform(-360, 720, n),
        rng.uniform(0, 90, n),
        rng.uniform(0, 360, n),
        rng.lognormal(-2, 2, (n, 3)) * rng.choice([1.0, -1.0], (n, 3), p=[0.9, 0.1]),
    )


def _assert_samples_equal(a, b):
    for f in ("theta_i", "phi_i", "theta_v", "phi_v", "rgb"):
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype == np.float64
        np.testing.assert_array_equal(x, y, err_msg=f)


def _no_temp_files(folder: Path):
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp")] == []


# ----------------------------------------------------------------------------- atomic_write


def test_atomic_write_replaces_on_success(tmp_path):
    p = tmp_path / "out.bin"
    p.write_bytes(b"old")
    with atomic_write(p) as f:
        f.write(b"new content")
        assert p.read_bytes() == b"old"  # not visible before the block ends
    assert p.read_bytes() == b"new content"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out.bin"]


def test_atomic_write_text_mode_and_str_path(tmp_path):
    p = tmp_path / "out.txt"
    with atomic_write(str(p), "w") as f:
        f.write("héllo\n")
    assert p.read_text(encoding="utf-8") == "héllo\n"
    umask = os.umask(0o022)
    os.umask(umask)
    if os.name == "posix":  # permissions of an ordinary new file, not mkstemp's 0o600
        assert p.stat().st_mode & 0o777 == 0o666 & ~umask


def test_atomic_write_exception_keeps_old_file(tmp_path):
    p = tmp_path / "keep.bin"
    p.write_bytes(b"precious")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_write(p) as f:
            f.write(b"half written")
            raise RuntimeError("boom")
    assert p.read_bytes() == b"precious"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["keep.bin"]


def test_atomic_write_exception_leaves_no_file(tmp_path):
    p = tmp_path / "new.bin"
    with pytest.raises(KeyError):
        with atomic_write(p) as f:
            f.write(b"x")
            raise KeyError("k")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_drop_cache_advises_after_the_fsync(tmp_path, monkeypatch):
    """``drop_cache``: the written, fsync-ed file's pages are released with posix_fadvise
    (DONTNEED) before the rename; not without ``durable``; a platform without the call or one
    that refuses it still writes the file."""
    calls = []
    monkeypatch.setattr(os, "fsync", lambda fd: calls.append(("fsync", fd)))
    monkeypatch.setattr(
        os,
        "posix_fadvise",
        lambda fd, off, n, advice: calls.append(("advise", advice)),
        raising=False,
    )
    monkeypatch.setattr(os, "POSIX_FADV_DONTNEED", 4, raising=False)
    p = tmp_path / "chunk.bin"
    with atomic_write(p, drop_cache=True) as f:
        f.write(b"x" * 10)
    assert p.read_bytes() == b"x" * 10
    assert [c[0] for c in calls[:2]] == ["fsync", "advise"] and calls[1][1] == 4
    calls.clear()
    with atomic_write(p, drop_cache=True, durable=False) as f:
        f.write(b"y")
    with atomic_write(p) as f:
        f.write(b"z")
    assert "advise" not in [c[0] for c in calls]

    def refuse(*a):
        raise OSError("not supported")

    monkeypatch.setattr(os, "posix_fadvise", refuse)
    with atomic_write(p, drop_cache=True) as f:
        f.write(b"w")
    monkeypatch.delattr(os, "posix_fadvise")
    with atomic_write(p, drop_cache=True) as f:
        f.write(b"v")
    assert p.read_bytes() == b"v"


def test_atomic_write_missing_folder(tmp_path):
    p = tmp_path / "nope" / "out.bin"
    with pytest.raises(InputError, match=r"cannot write .*out\.bin: folder .*nope does not exist"):
        with atomic_write(p) as f:
            f.write(b"x")


@pytest.mark.skipif(
    os.name != "posix" or os.geteuid() == 0, reason="needs POSIX permissions, non-root"
)
def test_atomic_write_unwritable_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(InputError, match="not writable"):
            with atomic_write(folder / "x.bin") as f:
                f.write(b"x")
    finally:
        folder.chmod(0o700)


def test_atomic_write_unwritable_folder_simulated(tmp_path, monkeypatch):
    """Same as above where the tests run as root: the temp file cannot be created."""
    import abrdf_jax.io._atomic as atomic

    def deny(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(atomic, "_create_temp", deny)
    with pytest.raises(InputError, match=r"cannot write .*x\.bin: folder .* is not writable"):
        with atomic_write(tmp_path / "x.bin") as f:
            f.write(b"x")


def test_atomic_write_onto_folder(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(InputError, match="is a folder"):
        with atomic_write(tmp_path / "d") as f:
            f.write(b"x")
    assert _no_temp_files(tmp_path)


def test_writers_into_missing_folder(tmp_path, rng):
    missing = tmp_path / "missing"
    with pytest.raises(InputError, match="does not exist"):
        write_samples_csv(missing / "s.csv", _random_samples(rng, 3))
    with pytest.raises(InputError, match="does not exist"):
        write_table(missing / "t.npz", np.zeros((81, 81, 3), np.float32))
    with pytest.raises(InputError, match="does not exist"):
        write_table(missing / "t.exr", np.zeros((81, 81, 3), np.float32))
    assert not missing.exists()


# ----------------------------------------------------------------------------- CSV


def test_csv_round_trip(tmp_path, rng):
    s = _random_samples(rng, 57)  # arbitrary directions: off-slice rows must pass unchanged
    p = tmp_path / "m.csv"
    write_samples_csv(p, s)
    assert p.read_text().splitlines()[0] == HEADER
    _assert_samples_equal(read_samples_csv(p), s)
    _assert_samples_equal(read_samples_csv(str(p)), s)
    assert _no_temp_files(tmp_path)


def test_csv_round_trip_extremes(tmp_path):
    tiny = np.nextafter(0.0, 1.0)
    s = Samples(
        np.array([0.0, 90.0, 45.1, 1e-300]),
        np.array([-360.0, 720.0, 0.1 + 0.2, 359.99999999999994]),
        np.array([90.0, 0.0, 1 / 3, 30.0]),
        np.array([0.0, -0.0, 15.0, 2.0 / 3.0]),
        np.array(
            [[tiny, -1e-12, 1e300], [0.0, 1.0, 2.0], [np.pi, np.e, 1e-310], [5e-324, -5.0, 7.0]]
        ),
    )
    p = tmp_path / "x.csv"
    write_samples_csv(p, s)
    _assert_samples_equal(read_samples_csv(p), s)


def test_csv_column_order_whitespace_and_extra_columns(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text(
        " B , note, phi_v,theta_v , r,g ,phi_i,theta_i,extra\n"
        "0.3,hello,10,20,0.1,0.2,30,40,x\n"
        "\n"
        "  6 ,, 50 , 60 ,4,5, 70 , 80 ,\n"
    )
    s = read_samples_csv(p)
    np.testing.assert_array_equal(s.theta_i, [40, 80])
    np.testing.assert_array_equal(s.phi_i, [30, 70])
    np.testing.assert_array_equal(s.theta_v, [20, 60])
    np.testing.assert_array_equal(s.phi_v, [10, 50])
    np.testing.assert_array_equal(s.rgb, [[0.1, 0.2, 0.3], [4, 5, 6]])


def test_csv_crlf_and_bom(tmp_path):
    p = tmp_path / "win.csv"
    p.write_bytes(("\ufeff" + HEADER + "\r\n10,20,30,40,1,2,3\r\n").encode("utf-8"))
    s = read_samples_csv(p)
    np.testing.assert_array_equal(s.rgb, [[1, 2, 3]])


def test_csv_negative_rgb_is_allowed(tmp_path):
    p = tmp_path / "neg.csv"
    p.write_text(HEADER + "\n10,20,30,40,-0.001,2,3\n")
    assert read_samples_csv(p).rgb[0, 0] == -0.001


@pytest.mark.parametrize(
    "content, line, match",
    [
        (None, None, "file not found"),
        ("", 1, "empty file"),
        ("\n\n", 1, "empty file"),
        (HEADER + "\n", None, "no data rows"),
        ("theta_i,phi_i,theta_v,r,g,b\n1,2,3,4,5,6\n", 1, "lacks column.*phi_v"),
        ("theta_i,phi_i,theta_v,phi_v,red,g,b\n1,2,3,4,5,6,7\n", 1, "lacks column.*r"),
        ("10,20,30,40,1,2,3\n", 1, "looks like data"),
        ("theta_i,phi_i,theta_v,phi_v,r,g,b,r\n", 1, "twice"),
        (HEADER + "\n10,20,30,40,1,2,3\n10,20,30,40,1,2\n", 3, "at least 7 fields"),
        (HEADER + "\n10,20,30,40,1,2,3\n10,abc,30,40,1,2,3\n", 3, "phi_i.*'abc'"),
        (HEADER + "\n10,20,30,40,1,,3\n", 2, "column 'g'"),
        (HEADER + "\n10,20,30,40,1,nan,3\n", 2, "'g'.*not finite"),
        (HEADER + "\n10,20,30,40,1,2,3\n10,20,30,inf,1,2,3\n", 3, "'phi_v'.*not finite"),
        (HEADER + "\n10,20,30,40,-Infinity,2,3\n", 2, "'r'.*not finite"),
        (HEADER + "\n10,20,95,40,1,2,3\n", 2, r"theta_v = 95 .*\[0, 90\]"),
        (HEADER + "\n-1,20,30,40,1,2,3\n", 2, r"theta_i = -1 "),
        (HEADER + "\n10,800,30,40,1,2,3\n", 2, r"phi_i = 800 .*\[-360, 720\]"),
        (HEADER + "\n10,20,30,-400,1,2,3\n", 2, r"phi_v = -400 "),
        (HEADER + '\n10,20,30,40,1,2,"3\n', None, "malformed CSV"),
        (HEADER + '\n10,20,30,40,1,"2"x,3\n', 2, "malformed CSV"),
    ],
)
def test_csv_bad_input(tmp_path, content, line, match):
    p = tmp_path / "bad.csv"
    if content is not None:
        p.write_text(content)
    with _raises(p, line, match):
        read_samples_csv(p)


def test_csv_not_text(tmp_path):
    p = tmp_path / "bin.csv"
    p.write_bytes(b"\xff\xfe\x00\x81\x90" * 20)
    with _raises(p, match="UTF-8"):
        read_samples_csv(p)


def test_csv_folder_instead_of_file(tmp_path):
    with _raises(tmp_path, match="folder"):
        read_samples_csv(tmp_path)


def test_csv_radians_detected(tmp_path, rng):
    n = 8
    theta = rng.uniform(0.2, 1.3, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    rows = [f"{a},{b},{c},{d},1,1,1" for a, b, c, d in zip(theta, phi, theta[::-1], phi[::-1])]
    p = tmp_path / "rad.csv"
    p.write_text(HEADER + "\n" + "\n".join(rows) + "\n")
    with _raises(p, match="radians.*degrees"):
        read_samples_csv(p)
    # The same numbers are fine when some angle is clearly in degrees.
    p.write_text(HEADER + "\n" + "\n".join(rows) + "\n30,0,30,0,1,1,1\n")
    assert len(read_samples_csv(p)) == n + 1
    # Few rows, or all azimuths zero, are not enough evidence.
    p.write_text(HEADER + "\n" + "\n".join(rows[:3]) + "\n")
    assert len(read_samples_csv(p)) == 3
    p.write_text(HEADER + "\n" + "0.5,0,0.5,0,1,1,1\n" * 5)
    assert len(read_samples_csv(p)) == 5


def test_csv_streamed_in_small_blocks(tmp_path, rng, monkeypatch):
    """Block boundaries (here every ~50 bytes) change nothing: values, BOM, CRLF, blank lines,
    quoted fields, and the line number of an error deep in the file."""
    import abrdf_jax.io._csv as csv_module

    monkeypatch.setattr(csv_module, "BLOCK_BYTES", 50)
    s = _random_samples(rng, 300)
    p = tmp_path / "m.csv"
    write_samples_csv(p, s)
    lines = p.read_text().splitlines()
    lines[100] = '"' + lines[100].replace(",", '","') + '"'  # a quoted row: the slow path
    lines.insert(200, "")
    p.write_bytes(("\ufeff" + "\r\n".join(lines) + "\r\n").encode("utf-8"))
    _assert_samples_equal(read_samples_csv(p), s)
    lines[249] = lines[249].replace(",", ",oops", 1)
    p.write_text("\n".join(lines) + "\n")
    with _raises(p, 250, "'oops"):
        read_samples_csv(p)


def test_write_csv_rejects_nonfinite_and_out_of_range(tmp_path, rng):
    s = _random_samples(rng, 4)
    # a NaN sample cannot even be built (Samples checks concrete values), so none reaches a file
    with pytest.raises(InputError, match=r"Samples\.rgb holds 3 NaN"):
        Samples(s.theta_i, s.phi_i, s.theta_v, s.phi_v, np.where(np.eye(4, 3) > 0, np.nan, s.rgb))
    p = tmp_path / "w.csv"
    bad = Samples(s.theta_i + 100, s.phi_i, s.theta_v, s.phi_v, s.rgb)
    with pytest.raises(InputError, match="theta_i"):
        write_samples_csv(p, bad)
    assert list(tmp_path.iterdir()) == []


def test_write_csv_accepts_jax_arrays(tmp_path, rng):
    s = _random_samples(rng, 5)
    fields = ("theta_i", "phi_i", "theta_v", "phi_v", "rgb")
    sj = Samples(*(jnp.asarray(getattr(s, f)) for f in fields))
    p = tmp_path / "j.csv"
    write_samples_csv(p, sj)
    _assert_samples_equal(read_samples_csv(p), s)


# ----------------------------------------------------------------------------- tables


@pytest.fixture
def table(rng):
    t = rng.lognormal(-3, 2, (81, 81, 3)).astype(np.float32)
    t[0, 0] = [0.0, np.float32(1e-40), np.finfo(np.float32).max]  # zero, subnormal, largest
    return t


@pytest.mark.parametrize("ext", [".npz", ".exr", ".NPZ", ".EXR"])
def test_table_round_trip_bit_exact(tmp_path, table, ext):
    p = tmp_path / f"t{ext}"
    write_table(p, table)
    back = read_table(p)
    assert back.dtype == np.float32 and back.shape == (81, 81, 3)
    assert back.tobytes() == table.tobytes()
    assert read_table(str(p)).tobytes() == table.tobytes()
    assert _no_temp_files(tmp_path)


def test_npz_bytes_is_what_numpy_savez_holds(tmp_path, table):
    """The in-memory archive of write_table (``_npz.npz_bytes``) holds the member numpy.savez
    writes, byte for byte, in a zip that numpy and zipfile read; equal arrays, equal bytes."""
    import io
    import zipfile

    from abrdf_jax.io._npz import npz_bytes

    for arr in (table, np.arange(6, dtype=">f8").reshape(2, 3), np.zeros((0,), np.int16)):
        data = npz_bytes("abrdf", arr)
        ref = io.BytesIO()
        np.savez(ref, abrdf=arr)
        with zipfile.ZipFile(io.BytesIO(data)) as ours, zipfile.ZipFile(ref) as theirs:
            assert ours.testzip() is None and ours.namelist() == theirs.namelist()
            assert ours.read("abrdf.npy") == theirs.read("abrdf.npy")
        back = np.load(io.BytesIO(data))["abrdf"]
        assert back.dtype == arr.dtype and back.tobytes() == arr.tobytes()
        assert npz_bytes("abrdf", arr.copy()) == data
    write_table(tmp_path / "t.npz", table)
    assert (tmp_path / "t.npz").read_bytes() == npz_bytes("abrdf", table)


def test_table_write_converts_float64_and_jax(tmp_path, table):
    p = tmp_path / "t.npz"
    write_table(p, jnp.asarray(table.astype(np.float64)))
    assert read_table(p).tobytes() == table.tobytes()


def test_table_exr_layout_and_foreign_files(tmp_path, table):
    """Row = illumination, column = view; plain RGB(A) / half EXRs from other tools are read."""
    import OpenEXR

    p = tmp_path / "t.exr"
    write_table(p, table)
    f = OpenEXR.File(str(p), separate_channels=True)
    np.testing.assert_array_equal(f.parts[0].channels["G"].pixels[5, 70], table[5, 70, 1])

    # An interleaved RGBA float32 image as other tools write it.
    rgba = np.concatenate([table, np.ones((81, 81, 1), np.float32)], axis=-1)
    q = tmp_path / "rgba.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGBA": rgba}).write(str(q))
    assert read_table(q).tobytes() == table.tobytes()

    # Half-float channels are widened to float32.
    h = (table / table.max()).astype(np.float16)
    q = tmp_path / "half.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": h}).write(str(q))
    np.testing.assert_array_equal(read_table(q), h.astype(np.float32))


def test_table_wrong_shape(tmp_path, table):
    p = tmp_path / "s.npz"
    np.savez(p, abrdf=table[:80])
    with _raises(p, match=r"shape \(80, 81, 3\), expected \(81, 81, 3\)"):
        read_table(p)
    np.savez(p, abrdf=np.stack([table, table]))
    with _raises(p, match=r"\(2, 81, 81, 3\).*stack"):
        read_table(p)
    with pytest.raises(InputError, match=r"shape \(81, 81\)"):
        write_table(tmp_path / "w.npz", table[..., 0])
    q = tmp_path / "small.exr"
    import OpenEXR

    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": table[:40]}).write(str(q))
    with _raises(q, match="81x40.*expected 81x81"):
        read_table(q)


def test_table_wrong_key_and_channels(tmp_path, table):
    import OpenEXR

    p = tmp_path / "k.npz"
    np.savez(p, table=table)
    with _raises(p, match="no array named 'abrdf'.*table"):
        read_table(p)
    q = tmp_path / "z.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Z": table[..., 0].copy()}).write(str(q))
    with _raises(q, match="lacks channel.*R, G, B.*Z"):
        read_table(q)


@pytest.mark.parametrize("ext", [".npz", ".exr"])
def test_table_truncated(tmp_path, table, ext):
    p = tmp_path / f"cut{ext}"
    write_table(p, table)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with _raises(p, match="truncated or corrupt"):
        read_table(p)


@pytest.mark.parametrize("ext", [".npz", ".exr"])
def test_table_not_that_format(tmp_path, ext):
    p = tmp_path / f"text{ext}"
    p.write_text("this is not an image\n" * 10)
    with _raises(p):
        read_table(p)
    p.write_bytes(b"")
    with _raises(p):
        read_table(p)
    with _raises(tmp_path / f"missing{ext}", match="not found"):
        read_table(tmp_path / f"missing{ext}")


def test_table_unknown_extension(tmp_path, table):
    with pytest.raises(InputError, match=r"t\.png.*unknown table format"):
        write_table(tmp_path / "t.png", table)
    (tmp_path / "t.npy").write_bytes(b"x")
    with pytest.raises(InputError, match=r"t\.npy.*unknown table format"):
        read_table(tmp_path / "t.npy")
    assert [p.name for p in tmp_path.iterdir()] == ["t.npy"]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e39])
def test_table_nonfinite(tmp_path, table, bad):
    t = table.astype(np.float64)
    t[3, 4, 2] = bad
    with pytest.raises(InputError, match=r"NaN or infinite.*illumination 3, view 4, channel B"):
        write_table(tmp_path / "n.npz", t)
    p = tmp_path / "n.npz"
    np.savez(p, abrdf=t)
    with _raises(p, match="NaN or infinite"):
        read_table(p)


def test_table_write_failure_keeps_old(tmp_path, table):
    p = tmp_path / "t.npz"
    write_table(p, table)
    before = p.read_bytes()
    with pytest.raises(InputError):
        write_table(p, table[:3])
    assert p.read_bytes() == before
    assert _no_temp_files(tmp_path)


def test_write_tables_equals_write_table(tmp_path, table):
    """The folder runs' batch writer: the same bytes and permissions as ``write_table``, the
    temporary names of ``atomic_write`` (writer pid), no temporary file left."""
    from abrdf_jax.io import write_tables
    from abrdf_jax.io._atomic import temp_owner

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    tables = [table, table[::-1].copy(), table.astype(np.float64)]
    names = ["x.npz", "y.npz", "z.exr"]
    write_tables([tmp_path / "a" / n for n in names], tables)
    for n, t in zip(names, tables):
        write_table(tmp_path / "b" / n, t, durable=False)
        a, b = tmp_path / "a" / n, tmp_path / "b" / n
        assert read_table(a).tobytes() == np.asarray(t, np.float32).tobytes()
        if n.endswith(".npz"):
            assert a.read_bytes() == b.read_bytes()
        assert a.stat().st_mode == b.stat().st_mode
    assert _no_temp_files(tmp_path / "a")
    seen = []
    real = os.open

    def spy(path, *args, **kw):
        seen.append(os.path.basename(path))
        return real(path, *args, **kw)

    import abrdf_jax.io._atomic as atomic

    atomic.os.open = spy
    try:
        write_tables([tmp_path / "a" / "w.npz"], [table])
    finally:
        atomic.os.open = real
    assert temp_owner(seen[0]) == os.getpid() and seen[0].startswith(".w.npz.")


def test_write_tables_failure_keeps_old_and_leaves_no_temp(tmp_path, table, monkeypatch):
    """A disk that fills up half-way through a table: that file keeps its old content, the
    tables before it are complete, the error names the file, no temporary file remains."""
    import errno

    from abrdf_jax.io import _atomic, write_tables

    paths = [tmp_path / f"t{k}.npz" for k in range(3)]
    paths[1].write_bytes(b"old")
    real, calls = _atomic._write_all, []

    def full(fd, data):  # the second table: half, then the disk is full
        calls.append(fd)
        if len(calls) == 2:
            real(fd, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd, data)

    monkeypatch.setattr(_atomic, "_write_all", full)
    with _raises(paths[1], match="No space left on device .disk full."):
        write_tables(paths, [table] * 3)
    monkeypatch.undo()
    assert read_table(paths[0]).tobytes() == table.tobytes()
    assert paths[1].read_bytes() == b"old" and not paths[2].exists()
    assert _no_temp_files(tmp_path)
    with _raises(tmp_path / "nope" / "t.npz", match="does not exist"):
        write_tables([tmp_path / "nope" / "t.npz"], [table])
    (tmp_path / "d.npz").mkdir()
    with _raises(tmp_path / "d.npz", match="is a folder"):
        write_tables([tmp_path / "d.npz"], [table])

    def deny(prefix):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(_atomic, "_open_temp", deny)
    with _raises(paths[2], match=r"folder .* is not writable \(Permission denied\)"):
        write_tables(paths[2:], [table])
    monkeypatch.undo()
    write_tables(paths, [table] * 3)  # an existing table replaced, a str path too
    write_tables([str(tmp_path / "s.npz")], [table])
    assert all(read_table(p).tobytes() == table.tobytes() for p in [*paths, tmp_path / "s.npz"])
    assert _no_temp_files(tmp_path)


# ----------------------------------------------------------------------------- MERL


@pytest.fixture(scope="module")
def merl_brdf():
    rng = np.random.default_rng(int(os.environ.get("ABRDF_TEST_SEED", "0")))
    b = rng.lognormal(-2, 1.5, MERL_SHAPE)
    b[0, 0, :3, 1] = -1.0 * MERL_SCALE[1]  # "no data" markers
    return b


def test_merl_round_trip(tmp_path, merl_brdf):
    p = tmp_path / "m.binary"
    write_merl_binary(p, merl_brdf)
    assert p.stat().st_size == 12 + 3 * 90 * 90 * 180 * 8
    back = read_merl_binary(str(p))
    assert back.dtype == np.float64 and back.shape == MERL_SHAPE
    np.testing.assert_allclose(back, merl_brdf, rtol=1e-15, atol=0)
    assert _no_temp_files(tmp_path)


def test_merl_layout(tmp_path):
    """The file layout written by hand (header, channel-major, scale) is read as documented."""
    raw = np.zeros((3, 90, 90, 180))
    raw[1, 7, 11, 13] = 1500.0  # G at (θh 7, θd 11, φd 13)
    raw[2, 89, 0, 179] = -1.0
    p = tmp_path / "hand.binary"
    p.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + raw.astype("<f8").tobytes())
    b = read_merl_binary(p)
    assert b[7, 11, 13, 1] == pytest.approx(1.15)
    assert b[89, 0, 179, 2] < 0
    assert np.count_nonzero(b) == 2
    flat = raw.reshape(3, -1)
    assert flat[1, (7 * 90 + 11) * 180 + 13] == 1500.0


def test_merl_bad_files(tmp_path, merl_brdf):
    p = tmp_path / "m.binary"
    write_merl_binary(p, merl_brdf)
    data = p.read_bytes()
    p.write_bytes(data[:-8])
    with _raises(p, match=f"{len(data) - 8} bytes, expected {len(data)}"):
        read_merl_binary(p)
    p.write_bytes(data + b"\0" * 8)
    with _raises(p, match="bytes, expected"):
        read_merl_binary(p)
    p.write_bytes(np.array([90, 90, 360], "<i4").tobytes() + data[12:])
    with _raises(p, match=r"\(90, 90, 360\), expected \(90, 90, 180\)"):
        read_merl_binary(p)
    p.write_bytes(b"\1\2")
    with _raises(p, match="too short"):
        read_merl_binary(p)
    nan = bytearray(data)
    nan[12 + 8 * 1000 : 12 + 8 * 1001] = np.array([np.nan], "<f8").tobytes()
    p.write_bytes(bytes(nan))
    with _raises(p, match="NaN"):
        read_merl_binary(p)
    with _raises(tmp_path / "none.binary", match="not found"):
        read_merl_binary(tmp_path / "none.binary")


def test_merl_write_rejects(tmp_path, merl_brdf):
    with pytest.raises(InputError, match=r"shape \(90, 90, 90, 3\)"):
        write_merl_binary(tmp_path / "a.binary", merl_brdf[:, :, :90])
    bad = merl_brdf.copy()
    bad[1, 2, 3, 0] = np.inf
    with pytest.raises(InputError, match="NaN or infinite"):
        write_merl_binary(tmp_path / "a.binary", bad)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def coded_brdf():
    """A BRDF whose value names its bin: 1 + h + 100 d + 10^4 p + 10^7 c."""
    axes = (np.arange(90), np.arange(90), np.arange(180), np.arange(3))
    h, d, p, c = np.meshgrid(*axes, indexing="ij")
    return jnp.asarray(1.0 + h + 100.0 * d + 1e4 * p + 1e7 * c, dtype=jnp.float64)


def _code(h, d, p):
    return np.array([1.0 + h + 100 * d + 1e4 * p + 1e7 * c for c in range(3)])


def test_merl_lookup_hand_chosen(coded_brdf):
    n = np.array([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(merl_lookup(coded_brdf, n, n), _code(0, 0, 0))
    # wi = wv at 45°: θh = 45°, bin floor(sqrt(1/2) * 90) = 63; θd = 0.
    w = np.asarray(to_vector(np.deg2rad(45.0), np.deg2rad(123.0)))
    np.testing.assert_array_equal(merl_lookup(coded_brdf, w, w), _code(63, 0, 0))
    # wi = (θ 60°, φ 0°), wv = (θ 20°, φ 0°): in the incidence plane, h at θ 40°, θd = 20.0° exact
    # boundary avoided by using 60.6 / 20.0 -> θh 40.3°, θd 20.3°, φd = 0 (d leans toward +x).
    wi = np.asarray(to_vector(np.deg2rad(60.6), 0.0))
    wv = np.asarray(to_vector(np.deg2rad(20.0), 0.0))
    ih = int(np.floor(np.sqrt(40.3 / 90.0) * 90))
    np.testing.assert_array_equal(merl_lookup(coded_brdf, wi, wv), _code(ih, 20, 0))


def test_merl_lookup_bin_centres(coded_brdf, rng):
    """Directions built from bin centres map back to their bins, also after swapping wi and wv."""
    k = 200
    h = rng.integers(1, 60, k)
    d = rng.integers(1, 89, k)
    p = rng.integers(0, 180, k)
    th = ((h + 0.5) / 90) ** 2 * (np.pi / 2)
    td = (d + 0.5) / 90 * (np.pi / 2)
    pd = (p + 0.5) / 180 * np.pi + np.pi * rng.integers(0, 2, k)  # reciprocity: φd + π same bin
    ph = rng.uniform(0, 2 * np.pi, k)
    wi, wv = (np.asarray(x) for x in vectors_from_half_diff(np.stack([th, ph, td, pd], -1)))
    above = (wi[:, 2] > 0) & (wv[:, 2] > 0)
    assert above.sum() > 50
    expect = np.where(above[:, None], np.stack([_code(*x) for x in zip(h, d, p)]), 0.0)
    np.testing.assert_array_equal(merl_lookup(coded_brdf, wi, wv), expect)
    np.testing.assert_array_equal(merl_lookup(coded_brdf, wv, wi), expect)


def test_merl_lookup_horizon_missing_broadcast_jit(coded_brdf):
    n = np.array([0.0, 0.0, 1.0])
    below = np.array([1.0, 0.0, -1e-3]) / np.linalg.norm([1.0, 0.0, -1e-3])
    grazing = np.array([1.0, 0.0, 0.0])
    np.testing.assert_array_equal(merl_lookup(coded_brdf, below, n), 0.0)
    np.testing.assert_array_equal(merl_lookup(coded_brdf, n, grazing), 0.0)
    b = coded_brdf.at[0, 0, 0, 1].set(-1.0)  # no data in G
    np.testing.assert_array_equal(merl_lookup(b, n, n), [1.0, 0.0, 1e7 * 2 + 1])
    # Broadcasting: one view against many illuminations; jit gives the same values.
    wi = np.asarray(to_vector(np.deg2rad(np.linspace(0, 80, 7)), np.linspace(0, 6, 7)))
    eager = merl_lookup(coded_brdf, wi, n)
    assert eager.shape == (7, 3)
    np.testing.assert_array_equal(jax.jit(merl_lookup)(coded_brdf, wi, n), eager)
    for k in range(7):
        np.testing.assert_array_equal(merl_lookup(coded_brdf, wi[k], n), eager[k])


def test_merl_lookup_bad_args(coded_brdf):
    n = np.array([0.0, 0.0, 1.0])
    with pytest.raises(InputError, match="brdf has shape"):
        merl_lookup(coded_brdf[:10], n, n)
    with pytest.raises(InputError, match=r"wv has shape \(2,\)"):
        merl_lookup(coded_brdf, n, n[:2])
    with pytest.raises(InputError, match="do not broadcast"):
        merl_lookup(coded_brdf, np.tile(n, (4, 1)), np.tile(n, (5, 1)))


def test_merl_lookup_gradient_wrt_brdf(coded_brdf):
    n = jnp.array([0.0, 0.0, 1.0])
    g = jax.grad(lambda b: merl_lookup(b, n, n).sum())(jnp.asarray(coded_brdf))
    assert float(g[0, 0, 0].sum()) == 3.0 and float(g.sum()) == 3.0


def test_merl_lookup_float32(coded_brdf):
    """float32 smoke test: at wi = wv the φd rounding noise is larger, the bin still (63, 0, 0)."""
    b32 = coded_brdf.astype(jnp.float32)
    w = jnp.asarray(to_vector(np.deg2rad(45.0), np.deg2rad(200.0)), dtype=jnp.float32)
    out = merl_lookup(b32, w, w)
    assert out.dtype == jnp.float32
    np.testing.assert_array_equal(out, _code(63, 0, 0).astype(np.float32))
