"""Whole BTFs (abrdf_jax.btf): generator, chunked store, EXR layout, streamed/resumed/sharded
reconstruction, command line.

One 8 x 8-texel BTF is generated and reconstructed once per module (chunks of 32 texels, one
shape, so each program compiles once); the other tests reuse it.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import btf
from abrdf_jax.cli import main
from abrdf_jax._errors import InputError
from abrdf_jax._grid import ubo_grid
from abrdf_jax.metrics import delta_e76, log_error
from abrdf_jax.btf import _store

SIZE, CHUNK = 8, 32
SEED = int(os.environ.get("ABRDF_TEST_SEED", "0"))  # as conftest.py
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    root = tmp_path_factory.mktemp("btf") / "gen"
    paths = btf.generate_btf(root, SIZE, seed=SEED, chunk=CHUNK)
    return root, paths


@pytest.fixture(scope="module")
def reconstructed(generated, tmp_path_factory):
    root, paths = generated
    out = tmp_path_factory.mktemp("rec") / "rec"
    stats = {}
    store = btf.reconstruct_btf(
        paths["measurements"], out, chunk=CHUNK, progress=False, stats=stats
    )
    return store, stats


def _tables(store) -> np.ndarray:
    return store.read().astype(np.float64).reshape(-1, 81, 81, 3)


# ------------------------------------------------------------------------------------ generator


def test_generator_is_deterministic_and_chunk_independent(generated):
    _, paths = generated
    meas = btf.ChunkedStore.open(paths["measurements"])
    ref = btf.ChunkedStore.open(paths["reference"])
    # maps=True: the program generate_btf compiled (one compilation for the module)
    again = btf.texel_chunk(btf.procedural_btf(SIZE, SEED), 0, CHUNK, maps=True, pad_to=CHUNK)
    np.testing.assert_array_equal(again["measurements"], meas.read(0, CHUNK))
    np.testing.assert_array_equal(again["reference"].astype(np.float16), ref.read(0, CHUNK))
    # the second chunk on its own (other padding) equals the stored one bit for bit
    part = btf.texel_chunk(
        btf.procedural_btf(SIZE, SEED), CHUNK + 3, 2 * CHUNK, maps=True, pad_to=CHUNK
    )
    np.testing.assert_array_equal(part["measurements"], meas.read(CHUNK + 3, 2 * CHUNK))
    other = btf.texel_chunk(btf.procedural_btf(SIZE, SEED + 1), 0, CHUNK, maps=True, pad_to=CHUNK)
    assert np.abs(other["measurements"] - again["measurements"]).mean() > 1e-3
    assert np.all(np.isfinite(again["reference"])) and again["reference"].min() >= 0
    with pytest.raises(InputError, match="size"):
        btf.procedural_btf(1, 0)


def _reciprocity_error(t):
    """Mean |f(i, v) - f(v, i)| / mean f, with f = ABRDF / cos θi (a BRDF)."""
    cos = np.cos(np.deg2rad(ubo_grid()[0]))
    f = t / cos[:, None, None]
    return np.abs(f - f.transpose(1, 0, 2)).mean() / f.mean()


def _rotation_error(t):
    """Mean |f(Ri, Rv) - f(i, v)| / mean f for a 90° rotation of both azimuths (on the rings
    whose azimuth counts are divisible by 4)."""
    theta, phi = ubo_grid()
    keep = np.isin(theta, (0.0, 30.0, 60.0, 75.0))
    idx = np.nonzero(keep)[0]
    rot = np.array(
        [
            np.nonzero(
                np.isclose(theta, theta[i])
                & np.isclose(phi, (phi[i] + 90) % 360 if theta[i] else 0)
            )[0][0]
            for i in idx
        ]
    )
    sub = t[np.ix_(idx, idx)]
    turned = t[np.ix_(rot, rot)]
    return np.abs(turned - sub).mean() / sub.mean()


def test_texels_are_anisotropic_and_nonreciprocal(generated):
    _, paths = generated
    tables = _tables(btf.ChunkedStore.open(paths["reference"]))
    # Controls: flat texels with an open horizon are what their materials are: reciprocal, and a
    # Lambertian one is isotropic. The measures below are therefore the generator's doing.
    flat = dict(
        normal=jnp.array([0.0, 0.0, 1.0]),
        albedo=jnp.array([0.5, 0.4, 0.3]),
        metal=jnp.array([0.6, 0.6, 0.6]),
        roughness=jnp.asarray(0.2),
        angle=jnp.asarray(0.3),
        fill=jnp.asarray(0.3),
        horizon=jnp.zeros(32),
    )
    controls = [
        btf.TexelModel(weights=jnp.array(w), aniso=jnp.asarray(a), **flat)
        for w, a in (([0.2, 0.4, 0.4], 3.0), ([1.0, 0.0, 0.0], 1.0))
    ]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *controls)
    ctl = np.asarray(jax.jit(jax.vmap(btf.dense_texel_table))(stacked), np.float64).reshape(
        -1, 81, 81, 3
    )
    assert _reciprocity_error(ctl[0]) < 1e-5
    assert _rotation_error(ctl[1]) < 1e-5
    assert _rotation_error(ctl[0]) > 0.05  # the anisotropic lobes alone
    recip = np.array([_reciprocity_error(t) for t in tables])
    aniso = np.array([_rotation_error(t) for t in tables])
    assert np.median(recip) > 0.05 and np.mean(recip > 0.02) > 0.8, recip
    assert np.median(aniso) > 0.05 and np.mean(aniso > 0.02) > 0.8, aniso


# ------------------------------------------------------------------------------------ store


def test_store_round_trip_and_corruption(tmp_path):
    rng = np.random.default_rng(SEED)
    data = rng.uniform(0, 10, (10, 5, 3)).astype(np.float32)
    for dtype in ("float32", "float16"):
        s = btf.ChunkedStore.create(
            tmp_path / dtype,
            kind="measurements",
            texel_shape=(2, 5),
            item_shape=(5, 3),
            dtype=dtype,
            chunk=4,
            geometry={"note": "test"},
        )
        assert s.n_chunks == 3 and s.done_chunks() == []
        for k, (a, b) in enumerate(s.chunk_ranges()):
            s.write_chunk(k, data[a:b])
        again = btf.ChunkedStore.open(tmp_path / dtype)
        assert again.complete and again.verify() == {}
        np.testing.assert_array_equal(again.read(), data.astype(dtype))
        np.testing.assert_array_equal(again.read(3, 9), data[3:9].astype(dtype))
    s = btf.ChunkedStore.open(tmp_path / "float32")
    npy, marker = s._files(1)
    raw = bytearray(npy.read_bytes())
    raw[-7] ^= 0x40  # one flipped bit in the data
    npy.write_bytes(bytes(raw))
    assert not s.is_done(1) and s.is_done(1, verify=False)  # same size: only the checksum sees it
    assert "checksum" in s.verify()[1]
    with pytest.raises(InputError, match="checksum"):
        s.read_chunk(1)
    npy.write_bytes(bytes(raw[:-20]))  # truncated
    assert "bytes" in s.chunk_status(1, verify=False)
    marker.unlink()
    assert s.chunk_status(1) == "missing"
    npy2, _ = s._files(2)
    npy2.unlink()
    assert "missing" in s.verify()[2]
    with pytest.raises(InputError, match="not valid"):
        s.read(0, 10)
    # a different store in the same folder is refused unless overwritten
    with pytest.raises(InputError, match="different"):
        btf.ChunkedStore.create(
            tmp_path / "float32",
            kind="measurements",
            texel_shape=(2, 5),
            item_shape=(5, 3),
            dtype="float32",
            chunk=5,
        )
    s2 = btf.ChunkedStore.create(
        tmp_path / "float32",
        kind="measurements",
        texel_shape=(2, 5),
        item_shape=(5, 3),
        dtype="float32",
        chunk=5,
        overwrite=True,
    )
    assert s2.done_chunks() == [] and not any((tmp_path / "float32" / "chunks").iterdir())
    with pytest.raises(InputError, match="NaN or infinite values .first at texel 0.; the chunk"):
        s2.write_chunk(0, np.full((5, 5, 3), np.nan))
    half = btf.ChunkedStore.open(tmp_path / "float16")
    # finite values beyond float16's range: a setting the user can change (exit 2 on the CLI)
    with pytest.raises(InputError, match=r"up to 1e\+06, beyond float16.*--dtype float32"):
        half.write_chunk(0, np.full((4, 5, 3), 1e6))
    with pytest.raises(ValueError, match="shape"):
        half.write_chunk(0, np.zeros((3, 5, 3)))
    with pytest.raises(InputError, match="not a chunked store"):
        btf.ChunkedStore.open(tmp_path)
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("x")
    with pytest.raises(InputError, match="not empty"):
        btf.ChunkedStore.create(
            tmp_path / "junk", kind="abrdf", texel_shape=(1, 1), item_shape=(1, 3)
        )


def test_store_checksums_new_and_older_markers(tmp_path):
    """Markers carry the CRC-32C of the whole chunk file (the standard check value of
    ``b"123456789"`` is 0xE3069283); a marker of an older store (zlib's CRC-32 under ``crc32``)
    still verifies, a wrong one of either kind or none at all is a checksum mismatch."""
    import zlib

    from abrdf_jax.btf._checksum import checksum

    assert checksum(b"1234", memoryview(b"56789")) == {"crc32c": 0xE3069283}
    s = btf.ChunkedStore.create(
        tmp_path / "s", kind="measurements", texel_shape=(1, 4), item_shape=(2, 3), chunk=4
    )
    s.write_chunk(0, np.arange(24, dtype=np.float32).reshape(4, 2, 3))
    npy, marker = s._files(0)
    m = json.loads(marker.read_text())
    assert m["crc32c"] == checksum(npy.read_bytes())["crc32c"] and "crc32" not in m
    old = {k: v for k, v in m.items() if k != "crc32c"}
    for crc, status in ((zlib.crc32(npy.read_bytes()), "done"), (12345, _store.CORRUPT)):
        marker.write_text(json.dumps(dict(old, crc32=crc)))
        assert s.chunk_status(0) == status
    np.testing.assert_array_equal(s.read_chunk(0, verify=False).ravel(), np.arange(24))
    for bad in (dict(m, crc32c=m["crc32c"] ^ 1), old):
        marker.write_text(json.dumps(bad))
        assert s.chunk_status(0) == _store.CORRUPT and s.chunk_status(0, verify=False) == "done"
        with pytest.raises(InputError, match="checksum"):
            s.read_chunk(0)


# ------------------------------------------------------------------------------------ batch path


def test_grouping_matches_group_slices(generated):
    """The chunk map puts flat samples into slices exactly as group_slices does for a CSV."""
    _, paths = generated
    meas = btf.ChunkedStore.open(paths["measurements"])
    y = meas.read(0, 3)
    cfg = btf.default_config()
    fn = btf.make_chunk_fn(
        cfg, aj.Params.default(cfg), meas.geometry, backend="pipeline", dtype=jnp.float64
    )
    got = fn.measurements(jnp.asarray(y, jnp.float64))
    g = meas.geometry
    for k in range(3):
        s = aj.Samples(*(np.asarray(g[c]) for c in ("theta_i", "phi_i", "theta_v", "phi_v")), y[k])
        want, _ = aj.group_slices(s, g["alpha_deg"], dtype=np.float64)
        np.testing.assert_array_equal(np.asarray(got.y[k]), np.asarray(want.y))
        np.testing.assert_allclose(np.asarray(got.t[k]), np.asarray(want.t), atol=1e-6)
        np.testing.assert_array_equal(np.asarray(got.count[k]), np.asarray(want.count))


def test_accuracy_beats_mean_fill(generated, reconstructed):
    _, paths = generated
    rec, stats = reconstructed
    assert stats["chunks_done"] == 2 and stats["chunks_skipped"] == 0
    both = btf.texel_metrics_many(
        dict(ours=rec, base=btf.mean_fill(paths["measurements"])),
        paths["reference"],
        metrics=("de76", "logerr"),
    )
    ours, base = both["ours"], both["base"]
    # the per-texel maps are the package's protocol metrics of each texel
    ref = btf.ChunkedStore.open(paths["reference"]).read(0, 3).astype(np.float32)
    for t, x in enumerate(rec.read(0, 3).astype(np.float32)):
        np.testing.assert_allclose(ours["de76"].ravel()[t], float(delta_e76(x, ref[t])), rtol=1e-5)
        np.testing.assert_allclose(
            ours["logerr"].ravel()[t], float(log_error(x, ref[t])), rtol=1e-5
        )
    assert ours["de76"].shape == (SIZE, SIZE)
    assert ours["de76"].mean() < 0.85 * base["de76"].mean(), (
        ours["de76"].mean(),
        base["de76"].mean(),
    )
    assert ours["logerr"].mean() < 0.85 * base["logerr"].mean()
    assert np.mean(ours["de76"] < base["de76"]) > 0.75


def test_resume_after_crash_equals_uninterrupted(generated, reconstructed, tmp_path, monkeypatch):
    _, paths = generated
    full, _ = reconstructed
    out = tmp_path / "rec"
    real = _store.atomic_write
    state = {"writes": 0}

    class Crash(RuntimeError):
        pass

    def crashing(path, mode="wb", **kw):
        cm = real(path, mode, **kw)
        if not str(path).endswith("c000001.npy"):
            return cm

        class Half:
            def __enter__(self):
                self.f = cm.__enter__()
                return self

            def write(self, data):
                self.f.write(bytes(data)[: len(data) // 2])  # half the chunk is on disk ...
                state["writes"] += 1
                raise Crash("simulated crash in the middle of a chunk")  # ... then the process dies

            def __exit__(self, *exc):
                return cm.__exit__(*exc)

        return Half()

    monkeypatch.setattr(_store, "atomic_write", crashing)
    with pytest.raises(Crash):
        btf.reconstruct_btf(paths["measurements"], out, chunk=CHUNK, progress=False)
    monkeypatch.setattr(_store, "atomic_write", real)
    assert state["writes"] == 1
    store = btf.ChunkedStore.open(out)
    assert store.done_chunks() == [0]
    assert not (out / "chunks" / "c000001.npy").exists()  # the half-written temporary file is gone
    # What a hard kill can leave behind (no cleanup ran): a stray temporary file and a truncated
    # chunk without marker. Neither looks valid.
    (out / "chunks" / ".c000001.npy.dead.tmp").write_bytes(b"\x93NUMPY partial")
    (out / "chunks" / "c000001.npy").write_bytes(
        (full.path / "chunks" / "c000001.npy").read_bytes()[:1000]
    )
    assert store.chunk_status(1) == "missing"
    stats = {}
    btf.reconstruct_btf(paths["measurements"], out, chunk=CHUNK, progress=False, stats=stats)
    assert stats["chunks_skipped"] == 1 and stats["chunks_done"] == 1
    assert not (out / "chunks" / ".c000001.npy.dead.tmp").exists()
    np.testing.assert_array_equal(btf.ChunkedStore.open(out).read(), full.read())
    # another configuration on the same folder is refused, before any work
    with pytest.raises(InputError, match="different"):
        btf.reconstruct_btf(
            paths["measurements"], out, aj.Config(budget="aniso204"), chunk=CHUNK, progress=False
        )


def test_two_processes_share_the_chunks(generated, reconstructed, tmp_path, monkeypatch):
    """Several hosts (jax.distributed) on one shared folder: process p of P computes the chunks
    k with k % P == p; together they give the one-process result. Simulated in this process."""
    _, paths = generated
    full, _ = reconstructed
    out = tmp_path / "rec"
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    for pid in (1, 0):
        monkeypatch.setattr(jax, "process_index", lambda pid=pid: pid)
        stats = {}
        btf.reconstruct_btf(paths["measurements"], out, chunk=CHUNK, progress=False, stats=stats)
        assert stats["chunks_done"] == 1 and stats["chunks_skipped"] == 0
        assert btf.ChunkedStore.open(out).done_chunks() == ([1] if pid == 1 else [0, 1])
    np.testing.assert_array_equal(btf.ChunkedStore.open(out).read(), full.read())
    # a second host creating the same store while the first is half-way (chunks/ and a temporary
    # manifest there, no manifest yet) is not refused as "a folder that holds something else"
    other = tmp_path / "race"
    (other / "chunks").mkdir(parents=True)
    (other / ".manifest.json.x1.tmp").write_text("{")
    s = btf.ChunkedStore.create(other, kind="abrdf", texel_shape=(1, 1), item_shape=(1, 3))
    assert s.done_chunks() == []
    with pytest.raises(InputError, match="together"):
        btf.init_distributed("localhost:1234")


def test_sharded_over_8_devices_equals_one_device(generated, reconstructed, tmp_path):
    """XLA_FLAGS must be set before JAX starts: a subprocess with 8 simulated CPU devices. In
    float32 (the default), 8, 2 and 1 devices give the same bits: every device multiplies blocks
    of the same shape. The same subprocess then dies by SIGKILL half-way through writing a chunk
    (a real crash: no cleanup runs), and this process resumes what it left."""
    _, paths = generated
    script = textwrap.dedent(f"""
        import os, signal, time
        import jax, numpy as np
        from abrdf_jax import btf
        from abrdf_jax.btf import _store
        assert len(jax.devices()) == 8, jax.devices()
        m = {str(paths["measurements"])!r}
        kw = dict(chunk={CHUNK}, block=4, progress=False, dtype="float32")
        for d in (8, 2, 1):
            s = {{}}
            btf.reconstruct_btf(m, {str(tmp_path)!r} + f"/r{{d}}", devices=d, stats=s, **kw)
            print("RUN", d, s["devices"], s["backend"], s["batch"], s["chunks_done"], flush=True)
        real = _store.atomic_write

        class Dying:
            def __init__(self, cm, path):
                self.cm, self.path = cm, path

            def __enter__(self):
                self.f = self.cm.__enter__()
                return self

            def write(self, data):
                self.f.write(bytes(data)[: len(data) // 2])
                self.f.flush()
                # chunks are written by parallel threads: die once chunk 0 has finished
                # (a kill earlier loses it too; it is then just missing, as chunk 1)
                marker = os.path.join(os.path.dirname(self.path), "c000000.json")
                for _ in range(600):
                    if os.path.exists(marker):
                        break
                    time.sleep(0.05)
                os.kill(os.getpid(), signal.SIGKILL)

            def __exit__(self, *exc):
                return self.cm.__exit__(*exc)

        def killing(path, mode="wb", **kw):
            cm = real(path, mode, **kw)
            return Dying(cm, str(path)) if str(path).endswith("c000001.npy") else cm

        _store.atomic_write = killing
        btf.reconstruct_btf(m, {str(tmp_path)!r} + "/crash", devices=1, **kw)
        print("SURVIVED", flush=True)
    """)
    env = dict(
        os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=8", JAX_PLATFORMS="cpu"
    )
    env.pop("JAX_ENABLE_X64", None)
    res = subprocess.run(
        [sys.executable, "-c", script],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=REPO,
    )
    assert res.returncode == -9 and "SURVIVED" not in res.stdout, (
        res.returncode,
        res.stderr[-3000:],
    )
    runs = [ln.split()[1:] for ln in res.stdout.splitlines() if ln.startswith("RUN")]
    assert runs == [[str(d), str(d), "operator", str(CHUNK), "2"] for d in (8, 2, 1)], runs
    one = btf.ChunkedStore.open(tmp_path / "r1").read()
    assert one.shape == (SIZE * SIZE, 6561, 3) and np.all(np.isfinite(one)) and one.max() > 0
    for d in (8, 2):
        np.testing.assert_array_equal(btf.ChunkedStore.open(tmp_path / f"r{d}").read(), one)
    # the same tables as this process's run (float16 store, operator built in float64 here)
    here = reconstructed[0].read().astype(np.float32)
    scale = here.reshape(len(here), -1).max(axis=1)[:, None, None]
    assert np.max(np.abs(one - here) / scale) < 5e-3

    # What the kill left: chunk 0 valid; of chunk 1 only a half-written temporary file.
    crash = btf.ChunkedStore.open(tmp_path / "crash")
    left = sorted(p.name for p in (tmp_path / "crash" / "chunks").iterdir())
    assert [n for n in left if not n.startswith(".")] == ["c000000.json", "c000000.npy"], left
    assert any(n.startswith(".c000001.npy.") for n in left), left
    assert crash.done_chunks() == [0] and crash.chunk_status(1) == "missing"
    stats = {}
    btf.reconstruct_btf(
        paths["measurements"],
        tmp_path / "crash",
        chunk=CHUNK,
        progress=False,
        dtype="float32",
        stats=stats,
    )
    assert stats["chunks_skipped"] == 1 and stats["chunks_done"] == 1
    assert not any(p.name.startswith(".") for p in (tmp_path / "crash" / "chunks").iterdir())
    resumed = btf.ChunkedStore.open(tmp_path / "crash")
    assert resumed.verify() == {}
    np.testing.assert_array_equal(resumed.read(0, CHUNK), one[:CHUNK])  # kept, not recomputed
    # chunk 1 recomputed here, by the operator built in float64 (there: float32)
    assert np.max(np.abs(resumed.read(CHUNK) - one[CHUNK:]) / scale[CHUNK:]) < 5e-3


# ------------------------------------------------------------------------------------ EXR layout


def test_exr_per_pair_round_trip(generated, tmp_path):
    _, paths = generated
    meas = btf.ChunkedStore.open(paths["measurements"])
    n = btf.write_exr_pairs(meas, tmp_path / "exr", half=False)
    files = sorted(p.name for p in (tmp_path / "exr").glob("*.exr"))
    assert n == 204 == len(files)
    assert btf.pair_filename(75, 15, 30, 120) == "tl075_pl015_tv030_pv120.exr"
    assert btf.parse_pair_filename("tl030_pl014.400_tv030_pv359.400.exr") == (
        30.0,
        14.4,
        30.0,
        359.4,
    )
    back = btf.read_exr_pairs(tmp_path / "exr", tmp_path / "store", chunk=CHUNK)
    assert back.kind == "measurements" and back.texel_shape == (SIZE, SIZE)
    np.testing.assert_array_equal(back.read(), meas.read())
    for key in ("theta_i", "phi_i", "theta_v", "phi_v", "alpha_deg", "budget"):
        assert back.geometry[key] == meas.geometry[key]
    # without the index the names alone give the angles (to 0.001°) and the same images
    (tmp_path / "exr" / "pairs.json").unlink()
    named = btf.read_exr_pairs(tmp_path / "exr", tmp_path / "store2", chunk=CHUNK)
    order = np.lexsort(
        np.array([meas.geometry[k] for k in ("phi_v", "theta_v", "phi_i", "theta_i")])
    )
    np.testing.assert_allclose(
        np.array(named.geometry["phi_v"]), np.array(meas.geometry["phi_v"])[order], atol=1e-3
    )
    np.testing.assert_array_equal(named.read(), meas.read()[:, order])
    assert named.geometry["budget"] == "aniso204" and abs(named.geometry["alpha_deg"] - 15.0) < 0.01
    (tmp_path / "exr" / files[0]).write_bytes(b"not an exr")
    with pytest.raises(InputError, match="OpenEXR"):
        btf.read_exr_pairs(tmp_path / "exr", tmp_path / "store3", chunk=CHUNK)


# ------------------------------------------------------------------------------------ command line


def test_cli_generate_reconstruct_evaluate(generated, reconstructed, tmp_path, capsys):
    _, paths = generated
    full, _ = reconstructed
    root = tmp_path / "cli"
    assert (
        main(
            [
                "btf",
                "generate",
                "-o",
                str(root),
                "--size",
                str(SIZE),
                "--seed",
                str(SEED),
                "--chunk",
                str(CHUNK),
                "-q",
            ]
        )
        == 0
    )
    np.testing.assert_array_equal(
        btf.ChunkedStore.open(root / "measurements").read(),
        btf.ChunkedStore.open(paths["measurements"]).read(),
    )
    maps = np.load(root / "maps.npz")
    assert maps["height"].shape == (SIZE, SIZE) and maps["normal"].shape == (SIZE, SIZE, 3)
    out = tmp_path / "out"
    assert main(["btf", "reconstruct", str(root), "-o", str(out), "--chunk", str(CHUNK), "-q"]) == 0
    np.testing.assert_array_equal(btf.ChunkedStore.open(out).read(), full.read())
    capsys.readouterr()
    assert (
        main(
            [
                "btf",
                "reconstruct",
                str(root / "measurements"),
                "-o",
                str(out),
                "--chunk",
                str(CHUNK),
                "-q",
            ]
        )
        == 0
    )
    assert "0 chunks computed, 2 already done" in capsys.readouterr().out  # resumed: nothing to do
    png = tmp_path / "map.png"
    assert (
        main(["btf", "evaluate", str(out), str(root / "reference"), "--json", "--png", str(png)])
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    want = btf.texel_metrics(full, paths["reference"], metrics=("de76", "logerr"))["de76"].mean()
    assert abs(doc["de76"]["mean"] - want) < 1e-6 * max(1.0, want) and png.stat().st_size > 1000
    # bad input: one line, exit status 2
    assert main(["btf", "reconstruct", str(tmp_path / "nothing"), "-o", str(tmp_path / "o2")]) == 2
    assert "not found" in capsys.readouterr().err
    assert (
        main(["btf", "reconstruct", str(root / "reference"), "-o", str(tmp_path / "o3"), "-q"]) == 2
    )
    assert "expected measurements" in capsys.readouterr().err
    assert main(["btf", "generate", "-o", str(tmp_path / "g"), "--size", "0"]) == 2
    capsys.readouterr()
    assert (
        main(
            [
                "btf",
                "reconstruct",
                str(root),
                "-o",
                str(tmp_path / "o4"),
                "--coordinator",
                "h:1",
                "-q",
            ]
        )
        == 2
    )
    assert "together" in capsys.readouterr().err
    assert main(["btf", "reconstruct", str(root), "-o", str(root / "maps.npz"), "-q"]) == 2
    assert "not a folder" in capsys.readouterr().err


# ------------------------------------------------------------------------- per-texel model choice


def _four_texel_store(path, s0, y):
    """A 2 × 2 measurement store of one chunk: the geometry of the samples ``s0`` (aniso204,
    α 15°), the values ``y`` ``(4, n, 3)``."""
    geometry = {k: np.asarray(getattr(s0, k)).tolist() for k in ("theta_i", "phi_i")}
    geometry |= {k: np.asarray(getattr(s0, k)).tolist() for k in ("theta_v", "phi_v")}
    geometry |= dict(alpha_deg=15.0, budget="aniso204")
    meas = btf.ChunkedStore.create(
        path,
        kind="measurements",
        texel_shape=(2, 2),
        item_shape=(len(s0), 3),
        chunk=4,
        geometry=geometry,
    )
    meas.write_chunk(0, y)
    return meas


def test_per_texel_model_choice(tmp_path):
    """model='auto': each texel gets the model its own isotropy test picks (the test of
    abrdf_jax.select, batched), and the store holds exactly that texel's reconstruction."""
    from abrdf_jax.select._isotropy import isotropy_test
    from abrdf_jax.btf import _batch
    from abrdf_jax.materials import get_material

    names = ("ggx-plastic", "ward-brushed-steel", "lambert-clay", "ggx-aniso-metal")
    samples = [aj.sample(get_material(n), aj.Config(budget="aniso204")) for n in names]
    s0 = samples[0]
    y = np.stack([np.asarray(s.rgb, np.float32) for s in samples])
    meas = _four_texel_store(tmp_path / "meas", s0, y)
    out = btf.reconstruct_btf(
        meas, tmp_path / "rec", chunk=4, progress=False, dtype="float32", model="auto"
    )

    decided = btf.isotropy_map(meas, chunk=4)
    truth = [isotropy_test(s, alpha_deg=15.0).isotropic for s in samples]
    assert decided["isotropic"].ravel().tolist() == truth == [True, False, True, False]
    assert decided["fraction_isotropic"] == 0.5

    config = btf.default_config()
    fn = _batch._chunk_fn(
        config,
        aj.Params.default(config, alpha_deg=15.0, dtype=jnp.float32),
        meas.geometry,
        "auto",
        jnp.float32,
        "auto",
    )  # the map reconstruct_btf built (cached)
    assert isinstance(fn, btf.ModelChoiceChunkFunction) and fn.backend == "operator+choice"
    assert isinstance(fn.iso, btf.BivariateChunkFunction)  # as reconstruct's auto choice
    iso, aniso = np.asarray(fn.iso(jnp.asarray(y))), np.asarray(fn.aniso(jnp.asarray(y)))
    for k in (0, 2):  # the isotropic texels: the library's bivariate model of their samples
        lib = aj.reconstruct_bivariate(samples[k]).reshape(-1, 3)
        np.testing.assert_allclose(iso[k], lib, rtol=2e-4, atol=1e-6 * lib.max())
    expected = np.where(np.asarray(truth)[:, None, None], iso, aniso)
    # rtol: float32 rounding; the kept rows' sparse sum (_kept_rows.kept_product) is fused
    # differently inside the store's jitted blocks than in a direct call (a few ulps after the exp)
    np.testing.assert_allclose(out.read(), expected, rtol=1e-5, atol=1e-7)
    assert np.abs(iso[1] - aniso[1]).max() > 1e-2  # the two models differ on the anisotropic texel

    with pytest.raises(InputError, match="model='auto'"):
        btf.reconstruct_btf(
            meas,
            tmp_path / "rec2",
            aj.Config.recommended("iso102"),
            chunk=4,
            progress=False,
            model="auto",
        )
    with pytest.raises(InputError, match="model must be"):
        btf.reconstruct_btf(meas, tmp_path / "rec3", chunk=4, progress=False, model="best")


def test_bivariate_model_per_texel(tmp_path, capsys, monkeypatch):
    """``model="bivariate"`` (and ``btf reconstruct --model bivariate``): every texel through the
    bivariate map of the store's geometry (its recorded angles), equal to the library call on
    that texel's samples; bad arguments are named. The command lets the allocator keep a chunk's
    output (``keep_chunk_outputs``: its size in bytes)."""
    from abrdf_jax.cli import _common, main
    from abrdf_jax.materials import get_material

    names = ("ggx-plastic", "lambert-clay", "ward-brushed-steel", "ggx-aniso-metal")
    samples = [aj.simulate_capture(get_material(n), jitter_deg=0.3, seed=1) for n in names]
    s0 = samples[0]
    # every texel at the first texel's angles (one geometry), with its own material's values
    rows = [aj.Samples(s0.theta_i, s0.phi_i, s0.theta_v, s0.phi_v, s.rgb) for s in samples]
    meas = _four_texel_store(
        tmp_path / "meas", s0, np.stack([np.asarray(r.rgb, np.float32) for r in rows])
    )
    out = btf.reconstruct_btf(
        meas, tmp_path / "rec", chunk=4, progress=False, dtype="float32", model="bivariate"
    )
    got = out.read().reshape(4, 81, 81, 3)
    for k, r in enumerate(rows):
        lib = aj.reconstruct_bivariate(r)
        np.testing.assert_allclose(got[k], lib, rtol=2e-4, atol=1e-6 * lib.max())
    assert out.attrs["job"]["model"] == "bivariate"
    cli = ["btf", "reconstruct", str(tmp_path / "meas"), "-o", str(tmp_path / "c")]
    kept = []
    monkeypatch.setattr(_common, "keep_freed_blocks", lambda largest=0: kept.append(largest))
    assert main([*cli, "--model", "bivariate", "-q", "--dtype", "float32", "--chunk", "8"]) == 0
    assert kept == [8 * 81 * 81 * 3 * 4]  # one chunk of float32 tables
    # the same map (float32 rounding: the command line pads the chunk to its own batch)
    np.testing.assert_allclose(btf.ChunkedStore.open(tmp_path / "c").read(), out.read(), rtol=1e-5)
    capsys.readouterr()
    bad = ["btf", "reconstruct", str(tmp_path / "meas"), "-o", str(tmp_path / "x")]
    assert main([*bad, "--model", "bivariate", "--preset", "paper"]) == 2
    assert "is not an RBF model" in capsys.readouterr().err
    with pytest.raises(InputError, match="lacks 'phi_i'"):
        btf.make_bivariate_chunk_fn({"theta_i": [10.0, 20.0]})
    with pytest.raises(InputError, match="one length >= 3"):
        btf.make_bivariate_chunk_fn(
            {k: [10.0, 20.0] for k in ("theta_i", "phi_i", "theta_v", "phi_v")}
        )


def test_keep_chunk_outputs_sizes_the_padded_batch(monkeypatch):
    """The allocator is asked to keep a chunk's output as the chunk map pads it on the devices
    (the next multiple of devices × block), not the bare chunk; a device count beyond the
    machine's is refused as ``reconstruct_btf`` refuses it."""
    from abrdf_jax.btf._devices import padded_batch
    from abrdf_jax.cli import _common
    from abrdf_jax.cli.btf import keep_chunk_outputs

    cases = ((1024, 1), (1024, 8), (1024, 3), (1000, 8), (10, 4))
    assert [padded_batch(c, d) for c, d in cases] == [1024, 1024, 1152, 1000, 12]
    kept = []
    monkeypatch.setattr(_common, "keep_freed_blocks", lambda largest=0: kept.append(largest) or 1)
    assert keep_chunk_outputs(1024, "float16", jax.local_devices()[:1] * 3)  # three "devices"
    assert keep_chunk_outputs(1000, "float32", 1)
    assert kept == [1152 * 6561 * 3 * 2, 1024 * 6561 * 3 * 4]  # blocks of 128 on one device too
    with pytest.raises(InputError, match="devices must be in"):
        keep_chunk_outputs(1024, "float16", len(jax.local_devices()) + 1)


def test_learned_models_per_texel_equal_their_numpy_entry(generated, tmp_path, capsys):
    """``model="prior"|"fused"`` (issue 14, "folder and BTF runs use it"): every texel through the
    learned model's entry collapsed to one matrix, in JAX, equals the numpy entry that
    ``abrdf-jax reconstruct --model prior|fused`` applies to that texel's samples (float32
    rounding); the command line writes the same store from a prior file, reports the backend,
    and refuses ``--prior`` with an RBF model and a corrupt prior file (exit 2, named)."""
    from abrdf_jax import prior as P
    from abrdf_jax.btf._chunkfn import grouping
    from abrdf_jax.prior._default import DEFAULT_RECIPE

    root, paths = generated
    tables, names = P.default_training_tables({**DEFAULT_RECIPE, "n": 12})
    small = P.train_prior(tables, names, k=6, lam=0.03)
    pfile = P.save_prior(small, tmp_path / "p.npz")
    meas = btf.ChunkedStore.open(paths["measurements"])
    config = btf.default_config(meas.geometry["budget"])
    alpha = float(meas.geometry.get("alpha_deg", aj.PROTOCOL_ALPHA_DEG))
    template, group = grouping(meas.geometry, config.pairs, alpha)
    y = meas.read(0, 6).astype(np.float32)
    slices = np.einsum("pn,cnk->cpk", group, y).reshape(6, *np.asarray(template.t).shape, 3)
    params = aj.Params.default(config, alpha_deg=alpha)
    for model in ("prior", "fused"):
        out = btf.reconstruct_btf(
            meas, tmp_path / model, chunk=CHUNK, progress=False, dtype="float32",
            model=model, prior=small,
        )  # fmt: skip
        got = out.read(0, 6).reshape(6, 81, 81, 3)
        entry = aj.compile_numpy_operator(
            small, template, params, budget=config.budget, fused=model == "fused"
        )
        want = entry.apply(slices)
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
        assert out.attrs["job"]["model"] == model and out.attrs["job"]["prior"]["sha256"]
    cli = tmp_path / "cli"
    argv = ["btf", "reconstruct", str(paths["measurements"]), "-o", str(cli), "--chunk"]
    argv += [str(CHUNK), "--dtype", "float32", "--model", "fused", "--prior", str(pfile), "-q"]
    assert main(argv) == 0
    assert "fused backend" in capsys.readouterr().out
    np.testing.assert_array_equal(btf.ChunkedStore.open(cli).read(), out.read())
    bad = ["btf", "reconstruct", str(paths["measurements"]), "-o", str(tmp_path / "x")]
    assert main([*bad, "--prior", str(pfile)]) == 2
    assert "--prior is read by --model prior|fused" in capsys.readouterr().err
    (tmp_path / "broken.npz").write_bytes(b"not a prior")
    assert main([*bad, "--model", "prior", "--prior", str(tmp_path / "broken.npz")]) == 2
    assert "broken.npz" in capsys.readouterr().err and not (tmp_path / "x").exists()
