"""BTF stores as zarr v3 groups (issue 15): the same values as the .npy store, read by xarray and
dask with named dims and direction coordinates, a corrupted chunk detected by its crc32c
checksum and recomputed on resume, a killed writer's partial chunk ignored, export round trip,
metadata consolidated once complete (xarray opens without its warning), chunk bytes fsync'ed
before their name appears. The SIGKILL test of the CLI: tests/test_btf_zarr_kill.py."""

import os
import warnings

import numpy as np
import pytest

pytest.importorskip("zarr")
xr = pytest.importorskip("xarray")
da = pytest.importorskip("dask.array")

from abrdf_jax import btf  # noqa: E402
from abrdf_jax._errors import InputError  # noqa: E402
from abrdf_jax._grid import ubo_grid  # noqa: E402

SIZE, CHUNK = 8, 32  # two chunks of four rows each


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    root = tmp_path_factory.mktemp("zbtf")
    paths = btf.generate_btf(root / "gen", SIZE, seed=0, chunk=CHUNK)
    npy = btf.reconstruct_btf(paths["measurements"], root / "rec", chunk=CHUNK, progress=False)
    z = btf.reconstruct_btf(
        paths["measurements"], root / "rec.zarr", chunk=CHUNK, progress=False, format="zarr"
    )
    return paths, npy, z


def test_zarr_equals_the_npy_store_and_reads_in_xarray_and_dask(stores):
    _, npy, z = stores
    values = npy.read()
    np.testing.assert_array_equal(z.read(), values)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # complete, so consolidated: no "Failed to open" warning
        ds = xr.open_zarr(z.path)
    arr = ds["abrdf"]
    assert arr.dims == ("y", "x", "light", "view", "rgb")
    assert arr.shape == (SIZE, SIZE, 81, 81, 3)
    np.testing.assert_array_equal(arr.values.reshape(values.shape), values)
    theta, phi = ubo_grid()
    np.testing.assert_allclose(ds["theta_light"].values, theta)
    np.testing.assert_allclose(ds["phi_view"].values, phi)
    for key in ("grid", "azimuth", "colour_space", "cos_weighted"):
        assert any(key in k for k in ds.attrs), (key, sorted(ds.attrs))
    d = da.from_zarr(str(z.path), component="abrdf")
    np.testing.assert_array_equal(d.compute().reshape(values.shape), values)


def test_a_corrupted_chunk_is_detected_and_recomputed_on_resume(stores, tmp_path):
    import shutil

    paths, npy, z = stores
    out = tmp_path / "copy.zarr"
    shutil.copytree(z.path, out)
    store = btf.open_store(out)
    path = store.chunk_file(1)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte: the crc32c no longer matches
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="chunk 1 .*not valid"):
        btf.open_store(out).read()
    assert btf.open_store(out).chunk_status(1) != "done"
    # a killed writer's partial chunk file is not a chunk name: ignored, and removed on resume
    partial = path.parent / (path.name + ".1234.partial")
    partial.write_bytes(b"half a chunk")
    stats = {}
    btf.reconstruct_btf(
        paths["measurements"], out, chunk=CHUNK, progress=False, format="zarr", stats=stats
    )
    assert stats["chunks_done"] == 1 and stats["chunks_skipped"] == 1
    assert not partial.exists()
    np.testing.assert_array_equal(btf.open_store(out).read(), npy.read())


def test_export_to_zarr_round_trips(stores, tmp_path):
    _, npy, _ = stores
    out = btf.export_zarr(npy.path, tmp_path / "exported.zarr", progress=False)
    np.testing.assert_array_equal(btf.open_store(out.path).read(), npy.read())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # consolidated before the rename
        assert xr.open_zarr(out.path)["abrdf"].shape == (SIZE, SIZE, 81, 81, 3)
    with pytest.raises(InputError, match="exists"):
        btf.export_zarr(npy.path, tmp_path / "exported.zarr", progress=False)


def test_metadata_is_consolidated_only_once_every_chunk_is_written(stores, tmp_path):
    import json

    _, npy, z = stores
    assert json.loads((z.path / "zarr.json").read_text())["consolidated_metadata"]
    part = btf.ZarrStore.create(tmp_path / "part.zarr", **_layout(npy))
    part.write_chunk(0, npy.read_chunk(0))
    part.finish()  # one chunk of two: left as it is
    assert json.loads((part.path / "zarr.json").read_text()).get("consolidated_metadata") is None
    with pytest.warns(RuntimeWarning, match="consolidated metadata"):
        xr.open_zarr(part.path)
    part.write_chunk(1, npy.read_chunk(1))
    part.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(
            xr.open_zarr(part.path)["abrdf"].values.reshape(npy.shape), npy.read()
        )


def test_a_chunk_name_appears_only_after_its_bytes_are_fsynced(stores, tmp_path, monkeypatch):
    """The chunk's bytes go to a temporary file that is fsync'ed before it is renamed onto the
    chunk's name, and the folder is fsync'ed after (the rename itself made durable)."""
    _, npy, _ = stores
    store = btf.ZarrStore.create(tmp_path / "d.zarr", **_layout(npy))
    target = store.chunk_file(1)
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.fstat(fd).st_ino))
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", os.stat(src).st_ino, os.fspath(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    store.write_chunk(1, npy.read_chunk(1))
    monkeypatch.undo()
    at = [i for i, e in enumerate(events) if e[0] == "replace" and e[2] == os.fspath(target)]
    assert len(at) == 1, events
    (i,) = at
    assert ("fsync", events[i][1]) in events[:i], "chunk renamed before its bytes were fsync'ed"
    assert ("fsync", os.stat(target.parent).st_ino) in events[i:], "folder not fsync'ed after"
    np.testing.assert_array_equal(store.read_chunk(1), npy.read_chunk(1))


def _layout(store) -> dict:
    return dict(
        kind="abrdf",
        texel_shape=store.texel_shape,
        item_shape=store.item_shape,
        dtype=store.dtype.name,
        chunk=store.chunk,
    )
