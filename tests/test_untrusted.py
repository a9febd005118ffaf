"""Untrusted files are read without executing or extracting anything (issue 16): no reader of the
package unpickles, no zip member may point outside its archive, and no member, array or image may
unpack past the size budget (``abrdf_jax.io._untrusted``); each refusal names the file. Every
file here is crafted by hand and small: a "bomb" declares its size, it does not hold it."""

import io as _io
import re
import stat
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from abrdf_jax import io
from abrdf_jax._errors import InputError
from abrdf_jax.btf._images import decode_image, open_source
from abrdf_jax.io._untrusted import BUDGET_ENV, MAX_BYTES, check_npz, size_budget
from abrdf_jax.prior._file import read_prior_file
from abrdf_jax.prior._inputs import read_training_tables

PACKAGE = Path(__file__).resolve().parents[1] / "abrdf_jax"
PNG = b"\x89PNG\r\n\x1a\n"


def test_every_np_load_in_the_package_refuses_pickles():
    calls = []
    for path in PACKAGE.rglob("*.py"):
        for m in re.finditer(r"np\.load\((.*)", path.read_text()):
            calls.append((path.name, m.group(1)))
    assert calls, "no np.load found: the check would be empty"
    assert all("allow_pickle=False" in rest for _, rest in calls), calls


def test_a_table_holding_a_pickled_object_is_refused(tmp_path):
    p = tmp_path / "evil.npz"
    np.savez(p, table=np.array([{"run": "code"}], dtype=object))
    with pytest.raises(InputError, match="evil.npz"):
        io.read_table(p)
    with pytest.raises(InputError, match=r"evil\.npz: array 'table' holds Python objects"):
        check_npz(p)


# ---------------------------------------------------------------------------------------------
# Zip members: names, links, sizes
# ---------------------------------------------------------------------------------------------


def _png8(side=2) -> bytes:
    from PIL import Image

    buf = _io.BytesIO()
    Image.new("RGB", (side, side), (10, 20, 30)).save(buf, format="PNG")
    return buf.getvalue()


def _zip_with(path: Path, name: str, data: bytes, symlink=False) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("tl000 pl000 tv000 pv000.png", _png8())
        info = zipfile.ZipInfo(name)
        info.compress_type = zipfile.ZIP_DEFLATED
        if symlink:
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
        z.writestr(info, data)
    return path


@pytest.mark.parametrize(
    "member, why",
    [
        ("../evil.png", "'..'"),
        ("sub/../../evil.png", "'..'"),
        ("/etc/evil.png", "absolute path"),
        ("C:/evil.png", "absolute path"),
        ("..\\evil.png", "'..'"),
    ],
)
def test_zip_member_paths_outside_the_archive_are_refused(tmp_path, member, why):
    archive = _zip_with(tmp_path / "cap.zip", member, _png8())
    with pytest.raises(InputError, match=rf"cap\.zip: member .*evil\.png' is .*{why}"):
        open_source(archive)


def test_a_symlink_member_is_refused(tmp_path):
    archive = _zip_with(tmp_path / "cap.zip", "link.png", b"/etc/passwd", symlink=True)
    with pytest.raises(InputError, match=r"cap\.zip: member 'link\.png' is a symbolic link"):
        open_source(archive)


def test_a_zip_bomb_is_refused_at_the_budget(tmp_path, monkeypatch):
    """A member that inflates far beyond its compressed size: refused from its declared size,
    before any of it is read, naming the member and the budget (here lowered to 64 kB)."""
    archive = _zip_with(tmp_path / "bomb.zip", "big.png", bytes(1 << 20))
    assert archive.stat().st_size < 8 << 10  # 1 MiB of zeros deflates to ~1 kB
    monkeypatch.setenv(BUDGET_ENV, str(64 << 10))
    with pytest.raises(
        InputError,
        match=r"bomb\.zip: member 'big\.png' declares 1048576 bytes.*"
        rf"budget of 65536 bytes.*{BUDGET_ENV}",
    ):
        open_source(archive)


def test_a_member_that_inflates_past_its_declared_size_is_refused(tmp_path):
    """The zip directory says 100 bytes; the data inflate to 1 MiB: the read stops at the
    declared size and the member is refused (CRC), never 1 MiB in memory."""
    archive = _zip_with(tmp_path / "lie.zip", "big.png", bytes(1 << 20))
    raw = bytearray(archive.read_bytes())
    size = struct.pack("<I", 1 << 20)
    for at in [m.start() for m in re.finditer(re.escape(size), raw)]:  # local + central header
        raw[at : at + 4] = struct.pack("<I", 100)
    archive.write_bytes(bytes(raw))
    with open_source(archive) as src:
        with pytest.raises(InputError, match=r"lie\.zip:big\.png: cannot read from the zip"):
            src.read("big.png")


def test_the_budget_comes_from_the_environment(monkeypatch):
    monkeypatch.delenv(BUDGET_ENV, raising=False)
    assert size_budget() == MAX_BYTES
    monkeypatch.setenv(BUDGET_ENV, "12345")
    assert size_budget() == 12345
    for bad in ("-1", "0", "lots"):
        monkeypatch.setenv(BUDGET_ENV, bad)
        with pytest.raises(InputError, match=rf"{BUDGET_ENV}='{bad}': expected a whole number"):
            size_budget()


# ---------------------------------------------------------------------------------------------
# Declared sizes: .npy headers, EXR data windows, PNG headers, MERL headers
# ---------------------------------------------------------------------------------------------


def _forged_npz(path: Path, name: str, shape: tuple) -> Path:
    """An .npz whose member ``name`` declares ``shape`` (float64) but holds 8 bytes of data."""
    header = {"descr": "<f8", "fortran_order": False, "shape": shape}
    buf = _io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(name + ".npy", buf.getvalue() + bytes(8))
    return path


def test_an_npy_header_declaring_a_huge_array_is_refused_before_allocating(tmp_path):
    p = _forged_npz(tmp_path / "prior.npz", "components", (1 << 20, 1 << 20))
    with pytest.raises(
        InputError,
        match=r"prior\.npz: array 'components' declares 8796093022208"
        " bytes.*over the size budget",
    ):
        read_prior_file(p)
    p = _forged_npz(tmp_path / "stack.npz", "abrdf", (4, 81, 81, 3))  # fits the budget
    with pytest.raises(
        InputError,
        match=r"stack\.npz: array 'abrdf' declares shape \(4, 81, 81, "
        r"3\) \(629856 bytes of float64\), but its member holds 8",
    ):
        read_training_tables([p])


def _forged_exr(path: Path, width: int, height: int) -> Path:
    """A valid 3x2 EXR whose header's data window is rewritten to ``width`` x ``height``."""
    io.write_table  # noqa: B018 - the EXR codec is io's
    from abrdf_jax.io._exr import write_rgb_exr

    write_rgb_exr(path, np.zeros((2, 3, 3), np.float32))
    raw = bytearray(path.read_bytes())
    at = raw.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    raw[at : at + 16] = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    path.write_bytes(bytes(raw))
    return path


def test_an_exr_header_declaring_a_huge_image_is_refused(tmp_path):
    p = _forged_exr(tmp_path / "huge.exr", 1 << 20, 1 << 20)
    with pytest.raises(
        InputError,
        match=r"huge\.exr: EXR image 1048576x1048576 declares "
        r"13194139533312 bytes.*over the size budget",
    ):
        decode_image(p.read_bytes(), str(p))
    with pytest.raises(
        InputError,
        match=r"huge\.exr: EXR image is 1048576x1048576 \(width x "
        r"height\), expected 81x81",
    ):
        io.read_table(p)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


@pytest.mark.parametrize(
    "depth, message",
    [  # Pillow's own bomb check refuses the 8-bit one as it opens it; the budget the 16-bit one
        (8, r"decompression bomb"),
        (16, r"image \(decoded\) declares 43200000000 bytes.*over the size budget"),
    ],
)
def test_a_png_header_declaring_a_huge_image_is_refused(depth, message):
    """An RGB PNG that says 60000 x 60000 (43 GB decoded) with a tiny pixel stream, 8-bit
    (Pillow decodes it) and 16-bit (the package's own decoder)."""
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, depth, 2, 0, 0, 0)
    data = PNG + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(bytes(64)))
    data += _chunk(b"IEND", b"")
    with pytest.raises(InputError, match=rf"big\.png: .*{message}"):
        decode_image(data, "big.png")


def test_a_merl_header_declaring_absurd_dimensions_is_refused(tmp_path):
    p = tmp_path / "m.binary"
    p.write_bytes(struct.pack("<3i", 1 << 30, 1 << 30, 1 << 30) + bytes(64))
    with pytest.raises(InputError, match=r"m\.binary: MERL header gives dimensions \(1073741824"):
        io.read_merl_binary(p)


def test_an_image_over_the_budget_is_refused_in_a_folder_and_decoded(tmp_path, monkeypatch):
    """The budget bounds a folder's files by their size and a decoded image by its pixels."""
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "a.png").write_bytes(_png8(side=100))  # 120000 bytes decoded
    monkeypatch.setenv(BUDGET_ENV, "50000")
    with open_source(tmp_path / "cap") as src:
        with pytest.raises(InputError, match=r"a\.png: image \(decoded\) declares 120000 bytes"):
            src.image("a.png")
    monkeypatch.setenv(BUDGET_ENV, "100")
    with open_source(tmp_path / "cap") as src:
        with pytest.raises(InputError, match=r"cap/a\.png: file declares \d+ bytes.*budget of 100"):
            src.read("a.png")


def test_the_command_line_refuses_a_hostile_archive_in_one_line(tmp_path, capsys):
    """``abrdf-jax btf import`` of a zip with a '../' member: exit 2, one line naming the archive
    and the member, no store."""
    from abrdf_jax.cli import main

    archive = _zip_with(tmp_path / "cap.zip", "../../evil.png", _png8())
    assert main(["btf", "import", str(archive), "-o", str(tmp_path / "store")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cap.zip: member '../../evil.png' is a path with '..'" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap.zip"]
