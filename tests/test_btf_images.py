"""Image captures of BTFs: PNG/JPEG/EXR per direction pair, folders and UBO2003-style zips, the
azimuth convention and the refusals (``abrdf_jax.btf.read_image_pairs``, ``btf import``).

Every image is made here from the procedural BTF (one small generated BTF per module).
"""

import io
import os
import shutil
import struct
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from abrdf_jax import btf
from abrdf_jax._errors import InputError
from abrdf_jax.btf._images import decode_image, srgb_table
from abrdf_jax.metrics import srgb_decode, srgb_encode
from cli_runner import call_cli

SIZE, CHUNK = 8, 16
SEED = int(os.environ.get("ABRDF_TEST_SEED", "0"))  # as conftest.py
REPO = Path(__file__).resolve().parents[1]
ANGLE_KEYS = ("theta_i", "phi_i", "theta_v", "phi_v")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The generated BTF's measurements and reference as float64 arrays, scaled into [0, 1]."""
    root = tmp_path_factory.mktemp("gen")
    paths = btf.generate_btf(root / "b", SIZE, seed=SEED, chunk=CHUNK, reference_dtype="float32")
    meas, ref = (btf.ChunkedStore.open(paths[k]) for k in ("measurements", "reference"))
    scale = 1.0 / float(meas.read().max())
    angles = np.array([meas.geometry[k] for k in ANGLE_KEYS], float).T  # (204, 4)
    m = np.clip(meas.read().astype(np.float64) * scale, 0, 1)
    r = np.clip(ref.read().astype(np.float64) * scale, 0, 1)
    return dict(meas=m, ref=r, angles=angles, store=meas)


def _codes(values, bits=8) -> np.ndarray:
    """sRGB code values of linear values in [0, 1]."""
    top = 2**bits - 1
    return np.round(top * np.asarray(srgb_encode(values), np.float64)).astype(np.uint16)


def _image(values, j) -> np.ndarray:
    return values[:, j].reshape(SIZE, SIZE, 3)


def _grid() -> np.ndarray:
    from abrdf_jax._grid import pair_grid

    return np.stack(pair_grid(), axis=1)


def _write_pngs(folder, values, angles, *, name=btf.pair_filename, subfolders=False) -> Path:
    """One 8-bit sRGB PNG per pair (UTIA's per-view sub-folders with ``subfolders``)."""
    folder = Path(folder)
    codes = _codes(values).astype(np.uint8)
    for j, a in enumerate(angles):
        path = folder / name(*a, suffix=".png")
        if subfolders:
            path = folder / f"tv{int(a[2]):03d}_pv{int(a[3]):03d}" / path.name
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(_image(codes, j)).save(path)
    return folder


def _sorted(angles) -> np.ndarray:
    """The order the reader gives pairs read from names: numeric (θi, φi, θv, φv)."""
    return np.lexsort(np.round(angles, 3).T[::-1])


def _stored_angles(store) -> np.ndarray:
    return np.array([store.geometry[k] for k in ANGLE_KEYS], float).T


def _zip(folder, archive, prefix="") -> Path:
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(Path(folder).rglob("*")):
            if p.is_file():
                z.write(p, prefix + p.relative_to(folder).as_posix())
    return archive


def _png16(codes, filters=(0, 1, 2, 3, 4)) -> bytes:
    """A 16-bit PNG (grey or RGB) of ``codes`` ``(H, W[, 3])``, row ``r`` with filter
    ``filters[r % 5]``: the forward filters written out here (Pillow cannot write 16-bit RGB)."""
    h, w = codes.shape[:2]
    channels = 1 if codes.ndim == 2 else codes.shape[2]
    raw = codes.astype(">u2").reshape(h, -1).view(np.uint8).astype(np.int32)
    bpp, out = 2 * channels, []
    for r in range(h):
        x, up = raw[r], raw[r - 1] if r else np.zeros_like(raw[r])
        left = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        ul = np.concatenate([np.zeros(bpp, np.int32), up[:-bpp]])
        kind = filters[r % len(filters)]
        if kind == 4:
            p = left + up - ul
            pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
        else:
            pred = [0 * x, left, up, (left + up) // 2][kind]
        out.append(bytes([kind]) + ((x - pred) % 256).astype(np.uint8).tobytes())

    def chunk(kind, body):
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 0 if channels == 1 else 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(b"".join(out)))
        + chunk(b"IEND", b"")
    )


# ------------------------------------------------------------------------------------ decoding


def test_srgb_decode_is_the_iec_curve_and_inverts_encode():
    q = np.linspace(0, 1, 2001)
    iec = np.where(q <= 0.04045, q / 12.92, ((q + 0.055) / 1.055) ** 2.4)  # IEC 61966-2-1
    np.testing.assert_allclose(np.asarray(srgb_decode(q)), iec, rtol=1e-6, atol=1e-7)
    t = np.linspace(0, 1, 2001)
    np.testing.assert_allclose(np.asarray(srgb_decode(srgb_encode(t))), t, atol=1e-6)
    for bits in (8, 16):
        table = srgb_table(bits)
        assert table.shape == (2**bits,) and table[0] == 0 and table[-1] == pytest.approx(1)
        codes = np.arange(2**bits) / (2**bits - 1)
        np.testing.assert_allclose(table, np.interp(codes, q, iec), atol=2e-6)


def test_png16_every_filter_and_grey_as_pillow_reads_it():
    rng = np.random.default_rng(SEED)
    codes = rng.integers(0, 65536, size=(11, 7, 3))
    rgb, what = decode_image(_png16(codes), "x.png")
    assert what == "16-bit sRGB" and rgb.dtype == np.float32
    np.testing.assert_array_equal(rgb, srgb_table(16)[codes])
    # a grey 16-bit PNG as Pillow writes it (its own filter choice) reads as Pillow reads it
    grey = rng.integers(0, 65536, size=(9, 13)).astype(np.uint16)
    buf = io.BytesIO()
    Image.fromarray(grey).save(buf, format="PNG")
    rgb, _ = decode_image(buf.getvalue(), "g.PNG")
    pillow = np.asarray(Image.open(io.BytesIO(buf.getvalue())))
    np.testing.assert_array_equal(rgb, np.repeat(srgb_table(16)[pillow][..., None], 3, axis=-1))
    with pytest.raises(InputError, match=r"bad\.png: PNG chunk 'IDAT' is truncated or corrupt"):
        data = _png16(codes)
        decode_image(data[:60] + bytes([data[60] ^ 255]) + data[61:], "bad.png")


# ------------------------------------------------------------------------------------ formats


def test_png_folder_with_view_subfolders(capture, tmp_path):
    src = _write_pngs(tmp_path / "png", capture["meas"], capture["angles"], subfolders=True)
    store = btf.read_image_pairs(src, tmp_path / "store", chunk=CHUNK)
    order = _sorted(capture["angles"])
    assert store.kind == "measurements" and store.texel_shape == (SIZE, SIZE)
    np.testing.assert_allclose(_stored_angles(store), capture["angles"][order], atol=1e-3)
    assert store.geometry["budget"] == "aniso204" and abs(store.geometry["alpha_deg"] - 15) < 0.01
    got, want = store.read(), capture["meas"][:, order]
    # exactly the decoded code values; within half a code value's step (slope <= 2.3 at 1)
    np.testing.assert_array_equal(got, srgb_table(8)[_codes(want)])
    assert np.abs(got - want).max() <= 2.28 * 0.5 / 255 + 1e-6
    assert store.attrs["images"] == ["8-bit sRGB"]
    assert store.attrs["angles"]["azimuth"] == "ccw" and store.attrs["angles"]["read_from"] == (
        "file names"
    )


def test_exr_in_a_zip_and_mixed_case_suffixes(capture, tmp_path):
    btf.write_exr_pairs(capture["store"], tmp_path / "exr", half=True)
    (tmp_path / "exr" / "pairs.json").unlink()
    for p in sorted((tmp_path / "exr").glob("*.exr"))[::3]:
        p.rename(p.with_suffix(".EXR"))
    folder = btf.read_image_pairs(tmp_path / "exr", tmp_path / "s1", chunk=CHUNK)
    zipped = btf.read_image_pairs(_zip(tmp_path / "exr", tmp_path / "e.zip"), tmp_path / "s2")
    order = _sorted(capture["angles"])
    half = capture["store"].read()[:, order].astype(np.float16).astype(np.float32)
    np.testing.assert_array_equal(folder.read(), half)
    np.testing.assert_array_equal(zipped.read(), folder.read())
    assert zipped.geometry == folder.geometry and folder.attrs["images"] == ["linear EXR"]


def _ubo_name(ti, pi, tv, pv, suffix=".jpg"):
    """The UBO2003 zips' member names: spaces between the angles."""
    return f"tl{ti:03.0f} pl{pi:03.0f} tv{tv:03.0f} pv{pv:03.0f}{suffix}"


def _jpeg(image) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="JPEG", quality=95, subsampling=0)
    return buf.getvalue()


def test_jpeg_ubo2003_zip(capture, tmp_path):
    """The UBO2003 download: 6561 JPEGs named 'tl075 pl015 tv030 pv120.jpg' in a sub-folder
    of the zip make an ABRDF store in table[i, v] order; a zip reads as its folder does."""
    grid, ref = _grid(), capture["ref"]
    codes = _codes(ref).astype(np.uint8)
    archive = tmp_path / "UBO_TEST256.zip"
    with zipfile.ZipFile(archive, "w") as z:  # in a shuffled order: the order does not matter
        for j in np.random.default_rng(SEED).permutation(len(grid)):
            z.writestr("UBO_TEST256/" + _ubo_name(*grid[j]), _jpeg(_image(codes, j)))
    store = btf.read_image_pairs(archive, tmp_path / "zip_store", chunk=CHUNK)
    assert store.kind == "abrdf" and store.item_shape == (6561, 3)
    err = np.abs(store.read().astype(np.float64) - ref)
    assert err.mean() < 0.01 and np.percentile(err, 99) < 0.06, (err.mean(), err.max())
    assert store.attrs["source"] == str(archive) and store.attrs["images"] == ["8-bit sRGB"]
    # the measurement pairs as UBO2003-named JPEGs in a folder, and zipped in a sub-folder
    folder, angles = tmp_path / "meas", capture["angles"]
    folder.mkdir()
    meas = _codes(capture["meas"]).astype(np.uint8)
    names = [btf.pair_filename(*a, suffix=".jpg").replace("_", " ") for a in angles]
    for j, name in enumerate(names):
        (folder / name).write_bytes(_jpeg(_image(meas, j)))
    in_folder = btf.read_image_pairs(folder, tmp_path / "f_store", chunk=CHUNK)
    zipped = _zip(folder, tmp_path / "meas.zip", prefix="Meas 256/")
    in_zip = btf.read_image_pairs(zipped, tmp_path / "z_store", chunk=CHUNK)
    np.testing.assert_array_equal(in_zip.read(), in_folder.read())
    assert in_zip.geometry == in_folder.geometry and in_zip.kind == "measurements"
    np.testing.assert_allclose(_stored_angles(in_zip), angles[_sorted(angles)], atol=1e-3)


# ------------------------------------------------------------------------------------ convention


def test_clockwise_names_and_light_offset_give_the_same_store(capture, tmp_path):
    vals, angles = capture["meas"], capture["angles"]
    ccw = btf.read_image_pairs(_write_pngs(tmp_path / "ccw", vals, angles), tmp_path / "s0")

    def cw_name(ti, pi, tv, pv, suffix):
        return btf.pair_filename(ti, (360 - pi) % 360, tv, (360 - pv) % 360, suffix)

    def offset_name(ti, pi, tv, pv, suffix):  # a device whose light φ is counted from φ = 180
        return btf.pair_filename(ti, (pi - 180) % 360, tv, pv, suffix)

    cw = btf.read_image_pairs(
        _write_pngs(tmp_path / "cw", vals, angles, name=cw_name), tmp_path / "s1", azimuth="cw"
    )
    shifted = btf.read_image_pairs(
        _write_pngs(tmp_path / "off", vals, angles, name=offset_name),
        tmp_path / "s2",
        light_offset_deg=180,
    )
    for other in (cw, shifted):
        np.testing.assert_array_equal(other.read(), ccw.read())
        np.testing.assert_allclose(_stored_angles(other), _stored_angles(ccw), atol=1e-9)
        assert other.geometry["budget"] == ccw.geometry["budget"]
    assert (
        cw.attrs["angles"]["azimuth"] == "cw" and shifted.attrs["angles"]["light_offset_deg"] == 180
    )
    # read as counter-clockwise, the clockwise names are the mirrored capture: other angles
    # read without the options they are another capture, which the estimated α shows
    assert ccw.geometry["alpha_deg"] == 15.0
    wrong = btf.read_image_pairs(tmp_path / "cw", tmp_path / "s3")
    assert not np.allclose(_stored_angles(wrong), _stored_angles(ccw))
    assert wrong.geometry["alpha_deg"] == 345.0  # 360° − α: the other handedness
    assert btf.read_image_pairs(tmp_path / "off", tmp_path / "s4").geometry["alpha_deg"] == 195.0
    np.testing.assert_allclose(
        btf.capture_angles([[30, 14.4, 0, 90]], "cw", 10), [[30, 355.6, 0, 0]], atol=1e-9
    )
    for bad, match in (
        (dict(azimuth="clockwise"), "azimuth must be one of"),
        (dict(light_offset_deg=float("nan")), "light_offset_deg must be a finite"),
        (dict(light_offset_deg="east"), "light_offset_deg must be a finite"),
    ):
        with pytest.raises(InputError, match=match):
            btf.read_image_pairs(tmp_path / "ccw", tmp_path / "bad", **bad)
        assert not (tmp_path / "bad").exists()


# ------------------------------------------------------------------------------------ refusals


def _refused(src, out, match, **kw):
    with pytest.raises(InputError, match=match):
        btf.read_image_pairs(src, out, chunk=CHUNK, **kw)
    assert not Path(out).exists(), "a refused import wrote something"


def test_refusals_write_nothing(capture, tmp_path):
    vals, angles = capture["meas"][:, :40], capture["angles"][:40]
    src = _write_pngs(tmp_path / "png", vals, angles)
    out = tmp_path / "out"
    files = sorted(src.iterdir())
    # an image of another size, named
    shutil.copy(files[7], tmp_path / "keep.png")
    Image.new("RGB", (SIZE, SIZE + 1)).save(files[7])
    _refused(src, out, rf"{files[7].name}: image is 8x9 .*, the first one .* 8x8")
    # corrupt images: in a folder and inside a zip (ZIP:member)
    files[7].write_bytes(b"\x89PNG\r\n\x1a\n not really")
    _refused(src, out, rf"{files[7].name}: cannot read as an image")
    archive = _zip(src, tmp_path / "c.zip", prefix="sub/")
    _refused(archive, out, rf"c\.zip:sub/{files[7].name}: cannot read as an image")
    files[7].write_bytes(files[8].read_bytes()[:60])  # truncated
    _refused(src, out, rf"{files[7].name}: cannot read as an image")
    shutil.copy(tmp_path / "keep.png", files[7])
    # nothing matching, in a folder and in a zip; a file that is neither
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no images")
    _refused(tmp_path / "empty", out, "no images named like tl030_pl000_tv030_pv000.png")
    _refused(_zip(tmp_path / "empty", tmp_path / "e.zip"), out, "e.zip: no images named like")
    _refused(tmp_path / "keep.png", out, "neither a folder nor a zip archive")
    _refused(tmp_path / "missing", out, "not found")
    # two images of one pair (the same name as PNG and JPEG)
    jpg = files[3].with_suffix(".jpg")
    Image.open(files[3]).save(jpg)
    _refused(src, out, "two images of the direction pair")
    jpg.unlink()
    # linear EXR mixed with sRGB PNG
    exr = tmp_path / "mixed"
    shutil.copytree(src, exr)
    from abrdf_jax.io._exr import write_rgb_exr

    write_rgb_exr(exr / files[0].with_suffix(".exr").name, np.zeros((SIZE, SIZE, 3)))
    (exr / files[0].name).unlink()
    _refused(exr, out, "mixes linear EXR images .* with sRGB PNG/JPEG images")
    # NaN or infinity in an EXR
    btf.write_exr_pairs(capture["store"], tmp_path / "exr", half=False)
    victim = sorted((tmp_path / "exr").glob("*.exr"))[5]
    bad = np.zeros((SIZE, SIZE, 3), np.float32)
    bad[2, 3, 1] = np.nan
    write_rgb_exr(victim, bad)
    _refused(
        tmp_path / "exr", out, rf"{victim.name}: holds NaN or infinite values .*row 2, column 3"
    )


def test_mixed_bit_depths_warn_and_are_recorded(capture, tmp_path):
    vals, angles = capture["meas"], capture["angles"]
    src = _write_pngs(tmp_path / "png", vals, angles)
    j = 11
    path = src / btf.pair_filename(*angles[j], suffix=".png")
    path.write_bytes(_png16(_codes(_image(vals, j), bits=16)))
    with pytest.warns(UserWarning, match="images of 16-bit sRGB and 8-bit sRGB"):
        store = btf.read_image_pairs(src, tmp_path / "s", chunk=CHUNK)
    assert store.attrs["images"] == ["16-bit sRGB", "8-bit sRGB"]
    k = int(np.flatnonzero((_sorted(angles) == j))[0])
    got = store.read()[:, k].astype(np.float64)
    assert np.abs(got - vals[:, j]).max() < 1e-4  # the 16-bit image's precision
    # files named like pairs in another format are left out with a warning
    Image.open(src / btf.pair_filename(*angles[0], suffix=".png")).save(
        src / "tl090_pl000_tv090_pv000.bmp"
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        btf.read_image_pairs(src, tmp_path / "s2", chunk=CHUNK)
    said = [str(w.message) for w in caught]
    assert any("1 file(s) named like direction pairs" in m and ".bmp" in m for m in said), said


def test_failure_after_the_first_group_removes_the_store(capture, tmp_path, monkeypatch):
    from abrdf_jax.btf import _images

    src = _write_pngs(tmp_path / "png", capture["meas"], capture["angles"])
    calls, real = [], _images.Source.image

    def flaky(self, name):
        calls.append(name)
        if len(calls) > 204 + 10:  # the second group of texels: the image changed meanwhile
            raise InputError(f"{self.label(name)}: cannot read as an image (changed?)")
        return real(self, name)

    monkeypatch.setattr(_images.Source, "image", flaky)
    with pytest.raises(InputError, match="changed"):
        # one chunk of 16 texels per group: 4 groups
        btf.read_image_pairs(src, tmp_path / "out", chunk=CHUNK, memory_limit=CHUNK * 204 * 12)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------ command line


def _cli(*args):
    return call_cli("btf", "import", *args, "-q", cwd=REPO)


def test_cli_import(capture, tmp_path):
    vals, angles = capture["meas"], capture["angles"]

    def cw_name(ti, pi, tv, pv, suffix):
        return btf.pair_filename(ti, (360 - pi) % 360, tv, (360 - pv) % 360, suffix)

    src = _write_pngs(tmp_path / "cw", vals, angles, name=cw_name)
    archive = _zip(src, tmp_path / "cw.zip")
    ok = _cli(archive, "-o", tmp_path / "s", "--azimuth", "cw", "--chunk", CHUNK)
    assert ok.returncode == 0, ok.stderr
    assert (
        "measurements store, 8x8 texels, 204 pairs per texel (8-bit sRGB; azimuths cw)" in ok.stdout
    )
    store = btf.ChunkedStore.open(tmp_path / "s")
    ref = btf.read_image_pairs(_write_pngs(tmp_path / "ccw", vals, angles), tmp_path / "r")
    np.testing.assert_array_equal(store.read(), ref.read())
    victim = sorted(src.iterdir())[4]
    victim.write_bytes(b"garbage")
    bad = _cli(src, "-o", tmp_path / "s2", "--azimuth", "cw")
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode == 2 and len(lines) == 1, bad.stderr
    assert f"{victim}: cannot read as an image" in lines[0]
    assert not (tmp_path / "s2").exists()
    bad = _cli(src, "-o", tmp_path / "s3", "--light-offset", "inf")
    assert bad.returncode == 2 and "--light-offset (degrees) must be a finite number" in bad.stderr
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the store written by the CLI opens without a warning
        assert btf.ChunkedStore.open(tmp_path / "s").attrs["angles"]["azimuth"] == "cw"


def test_btf_reconstruct_reads_an_image_capture_directly(capture, tmp_path):
    """``btf reconstruct ZIP -o OUT`` imports the images to ``OUT.measurements`` (once: a rerun
    reuses it) and reconstructs them, as import followed by reconstruct does."""
    vals, angles = capture["meas"], capture["angles"]
    archive = _zip(_write_pngs(tmp_path / "png", vals, angles), tmp_path / "cap.zip")
    cmd = ["btf", "reconstruct", archive, "-o", tmp_path / "rec", "-q", "--chunk", CHUNK]
    first = call_cli(*cmd, cwd=REPO)
    assert first.returncode == 0, first.stderr
    assert "importing the images of" in first.stdout
    rec = btf.ChunkedStore.open(tmp_path / "rec")
    assert rec.kind == "abrdf" and rec.item_shape[0] == 81 * 81 and not rec.verify()
    imported = btf.ChunkedStore.open(tmp_path / "rec.measurements")
    direct = btf.read_image_pairs(tmp_path / "png", tmp_path / "direct")
    np.testing.assert_array_equal(imported.read(), direct.read())
    again = call_cli(*cmd, cwd=REPO)
    assert again.returncode == 0 and "reused" in again.stdout, again.stderr
