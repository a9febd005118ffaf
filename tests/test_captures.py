"""Real captures (issue 12): dense, jittered, noisy, any pairs and α, gaps, through the API and CLI.

Every capture is made by ``abrdf_jax.simulate_capture`` of an analytic material (no shared data
needed); accuracy is measured against the material's dense table.
"""

import json
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials, metrics
from abrdf_jax.cli import main
from cli_runner import call_cli

ISO, ANISO = "ggx-plastic", "ward-brushed-steel"
OFF_UBO = ((35.0, 35.0), (35.0, 70.0), (70.0, 35.0), (70.0, 70.0))
EXTRA = aj.PROTOCOL_PAIRS + ((45.0, 45.0), (60.0, 60.0))


@pytest.fixture(scope="module")
def iso():
    m = materials.get_material(ISO)
    return m, materials.dense_table(m)


def de76(samples, ref, budget="iso102"):
    """ΔE76 of the recommended reconstruction of ``samples`` (pairs and α read off the data)."""
    rec = aj.reconstruct(samples, aj.preset("recommended", budget))
    return float(metrics.evaluate(rec, ref)["de76"])


def test_jittered_samples_are_used_at_their_true_positions():
    """0.5° encoder jitter: every sample is used (tolerance from the offsets' spread), at the
    orthogonal projection onto its slice, so ``φi − φv`` of a diagonal sample is kept exactly."""
    m = materials.get_material(ANISO)
    s = aj.simulate_capture(m, jitter_deg=0.5, seed=1)
    meas, rep = aj.group_slices(s)
    assert rep["n_used"] == len(s) and rep["n_off_slice"] == 0
    assert 1.5 < rep["tol_deg"] <= 5.0 and 0.4 < rep["offset_sigma_deg"] < 1.1
    assert abs(rep["alpha_deg"] - 15.0) < 4 * rep["alpha_se_deg"] + 0.05
    assert meas.pairs == aj.PROTOCOL_PAIRS
    # the diagonal slice of pair 0: projected positions keep each sample's φi − φv
    exact, _ = aj.group_slices(s, alpha_deg=rep["alpha_deg"], tol_deg=5.0)
    t = np.rad2deg(np.asarray(exact.t[1, : int(exact.count[1])]))
    on = (np.abs(np.asarray(s.theta_i) - 30) < 2.5) & (np.abs(np.asarray(s.theta_v) - 30) < 2.5)
    off = (np.asarray(s.phi_i) + np.asarray(s.phi_v) - rep["alpha_deg"] + 180) % 360 - 180
    diag = on & (np.abs(off) <= 5.0) & (np.abs(off) < 90)
    d_true = np.sort((np.asarray(s.phi_i) - np.asarray(s.phi_v))[diag] % 360)
    d_proj = np.sort((rep["alpha_deg"] - 2 * t) % 360)
    assert d_true.shape == d_proj.shape
    assert np.allclose(d_true, d_proj, atol=1e-3)


def test_slices_keep_the_recorded_directions_of_their_samples():
    """``SliceArrays.directions``: each slot's recorded ``(wi, wv)``; an exact capture's are the
    slice positions' own directions, a jittered one's its samples' (one sample per slot, the
    set of slots equal to the set of samples on the pair's diagonal slice), and a slot that
    averages repeated samples holds their normalised mean."""
    from abrdf_jax._grouping import group_arrays
    from abrdf_jax._grid import to_vector
    from abrdf_jax._slices import slice_vectors

    m = materials.get_material(ISO)
    exact, _ = group_arrays(aj.simulate_capture(m, budget="iso102").to_numpy(), dtype=np.float64)
    for s in range(exact.t.shape[0]):
        c = int(exact.count[s])
        wi, wv = slice_vectors(exact.t[s, :c], s % 2, exact.pairs[s // 2], np.deg2rad(15.0), np)
        np.testing.assert_allclose(exact.directions[s, :c, 0], wi, atol=1e-9)
        np.testing.assert_allclose(exact.directions[s, :c, 1], wv, atol=1e-9)
        assert not exact.directions[s, c:].any()  # padding
    jit = aj.simulate_capture(m, budget="iso102", jitter_deg=0.5, seed=3).to_numpy()
    grouped, rep = group_arrays(jit, dtype=np.float64)
    assert rep["n_used"] == len(jit)
    rad = [np.deg2rad(np.asarray(a)) for a in (jit.theta_i, jit.phi_i, jit.theta_v, jit.phi_v)]
    recorded = np.concatenate([to_vector(rad[0], rad[1], np), to_vector(rad[2], rad[3], np)], 1)
    c = int(grouped.count[1])  # the diagonal slice of (30, 30)
    slots = grouped.directions[1, :c].reshape(c, 6)
    near = np.abs(recorded[None, :, :] - slots[:, None, :]).max(-1).min(-1)
    assert near.max() < 1e-12  # every slot is one recorded sample, not its projection
    # a second copy moved across the diagonal slices (φi + φv by 0.2°, the same projections):
    # each slot averages a sample and its copy, and holds their directions' normalised mean
    from abrdf_jax._arrays import SampleColumns

    one = aj.simulate_capture(m, budget="iso102").to_numpy()
    cols = [np.asarray(a, np.float64) for a in (one.theta_i, one.phi_i, one.theta_v, one.phi_v)]
    moved = [cols[0], cols[1] + 0.1, cols[2], cols[3] + 0.1]
    both, _ = group_arrays(
        SampleColumns(*(np.r_[a, b] for a, b in zip(cols, moved)), np.ones((2 * len(one), 3))),
        alpha_deg=15.0,
        tol_deg=1.0,
        dtype=np.float64,
    )
    assert np.array_equal(both.count, exact.count)  # the copies share their samples' slots
    means = []
    for th, ph in ((0, 1), (2, 3)):
        w = [to_vector(np.deg2rad(c[th]), np.deg2rad(c[ph]), np) for c in (cols, moved)]
        mean = (w[0] + w[1]) / 2
        means.append(mean / np.linalg.norm(mean, axis=-1, keepdims=True))
    means = np.concatenate(means, 1)  # (n, 6): each sample's and its copy's mean
    for s in np.nonzero(both.count)[0]:  # iso102: the diagonal slices
        slots = both.directions[s, : int(both.count[s])].reshape(-1, 6)
        near = np.abs(means[None, :, :] - slots[:, None, :]).max(-1).min(-1)
        assert near.max() < 1e-12


def test_far_off_slice_samples_are_counted_not_used():
    m = materials.get_material(ISO)
    s = aj.simulate_capture(m, budget="iso102")
    stray = aj.Samples(
        np.array([30.0, 30.0]), np.array([100.0, 40.0]), np.array([30.0, 75.0]),
        np.array([7.0, 300.0]), np.ones((2, 3)),
    )  # fmt: skip
    _, rep = aj.group_slices(aj.Samples.concatenate([s, stray]))
    assert rep["n_off_slice"] == 2 and rep["n_used"] == len(s)


def test_dense_slices_are_reduced_keep_the_peak_and_are_not_worse(iso):
    m, ref = iso
    proto = aj.simulate_capture(m, budget="iso102")
    dense = aj.simulate_capture(m, budget="iso102", per_slice=5000)
    meas, rep = aj.group_slices(dense)
    assert int(np.max(np.asarray(meas.count))) <= 360 and meas.t.shape[-1] <= 360
    assert rep["n_raw"][1::2] == [5000] * 4
    # the reduction keeps the slice peak to within its bin (1 deg): >= 97 % of the raw maximum
    raw = np.asarray(dense.rgb)[:5000].max()
    assert np.asarray(meas.y[1]).max() >= 0.97 * raw
    assert de76(dense, ref) < de76(proto, ref)


def test_elevations_off_the_ubo_rings_are_inferred_and_reconstructed(iso):
    m, ref = iso
    s = aj.simulate_capture(m, budget="iso102", pairs=OFF_UBO)
    meas, rep = aj.group_slices(s)
    assert meas.pairs == OFF_UBO and rep["n_used"] == len(s) and rep["dropped_pairs"] == []
    proto = de76(aj.simulate_capture(m, budget="iso102"), ref)
    assert de76(s, ref) < 1.5 * proto


def test_jittered_captures_of_one_off_ring_device_share_their_pairs(iso):
    """A level off the UBO rings is rounded to ``LEVEL_STEP_DEG``: captures of one device with
    encoder error get the same pairs (a folder of them then shares one RBF map), and a level is
    never moved by more than half a step."""
    from abrdf_jax import _grouping

    m, _ = iso
    step = _grouping.LEVEL_STEP_DEG
    pairs = [
        aj.group_slices(aj.simulate_capture(m, pairs=OFF_UBO, jitter_deg=0.5, seed=k))[0].pairs
        for k in range(6)
    ]
    assert len(set(pairs)) <= 2 and pairs.count(OFF_UBO) >= 4
    for got in pairs:
        for a, b in zip(np.ravel(got), np.ravel(OFF_UBO)):
            assert abs(a - b) <= step and (a / step) == round(a / step)


def test_extra_pairs_are_used_and_help(iso):
    m, ref = iso
    s = aj.simulate_capture(m, budget="iso102", pairs=EXTRA)
    meas, rep = aj.group_slices(s)
    assert set(meas.pairs) == set(EXTRA) and rep["dropped_pairs"] == []
    assert de76(s, ref) < 0.95 * de76(aj.simulate_capture(m, budget="iso102"), ref)


def test_a_gap_is_reported_and_bridged(iso):
    m, ref = iso
    s = aj.simulate_capture(m, budget="iso102", per_slice=120, gap_deg=20.0)
    meas, rep = aj.group_slices(s)
    gaps = {(tuple(g["pair"]), g["slice"]) for g in rep["gaps"]}
    assert gaps == {((30.0, 30.0), "diagonal"), ((75.0, 75.0), "diagonal")}
    assert all(10 < (g["end_deg"] - g["start_deg"]) % 360 < 60 for g in rep["gaps"])
    full = aj.simulate_capture(m, budget="iso102", per_slice=120)
    assert de76(s, ref) < 1.25 * de76(full, ref)


def test_other_alpha_is_estimated_with_its_uncertainty():
    m = materials.get_material(ANISO)
    s = aj.simulate_capture(m, alpha_deg=27.5, jitter_deg=0.3, seed=4)
    _, rep = aj.group_slices(s)
    assert abs(rep["alpha_deg"] - 27.5) < max(4 * rep["alpha_se_deg"], 0.05)
    assert 0 < rep["alpha_se_deg"] < 0.1


def test_an_offset_of_zero_is_reported_as_zero_not_360():
    """Slices at α = 0 read through float32 angles land just under 360°: the estimate says 0."""
    from abrdf_jax._grouping import _alpha_spread

    phi_i = np.array([10.0, 50.0, 90.0, 130.0, 200.0])
    for offset in (8e-6, -8e-6, 0.0):
        alpha, _, _ = _alpha_spread(phi_i, phi_i + offset)
        assert abs(alpha) < 1e-4, (offset, alpha)
    assert _alpha_spread(phi_i, phi_i - 15.0)[0] == 15.0


def test_noise_is_estimated(iso):
    m, _ = iso
    dense = aj.simulate_capture(m, budget="iso102", per_slice=300, noise=0.05, seed=2)
    meas, _ = aj.group_slices(dense)
    from abrdf_jax.select import estimate_noise

    sigma = estimate_noise(meas, slices="all")
    assert 0.03 < sigma < 0.08  # relative noise 5 % is about 0.05 in log units
    clean, _ = aj.group_slices(aj.simulate_capture(m, budget="iso102", per_slice=300))
    assert estimate_noise(clean, slices="all") < 0.01


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(pairs=()), "pairs"),
        (dict(pairs=((30.0,),)), "pairs"),
        (dict(tol_deg=-1.0), "tol_deg"),
        (dict(tol_deg=float("nan")), "tol_deg"),
        (dict(alpha_deg=float("inf")), "alpha_deg"),
        (dict(max_knots=2), "max_knots"),
        (dict(centre_azimuths="dense"), "centre_azimuths"),
        (dict(centre_azimuths=0), "centre_azimuths"),
    ],
)
def test_group_slices_names_a_bad_argument(kw, match):
    s = aj.simulate_capture(materials.get_material(ISO), budget="iso102")
    with pytest.raises(aj.InputError, match=f"group_slices: {match}"):
        aj.group_slices(s, **kw)


def test_sample_folds_keep_short_slices_whole():
    """A slice too short to hold samples out stays whole in every fold (no error)."""
    m = materials.get_material(ANISO)
    meas, _ = aj.group_slices(aj.simulate_capture(m, per_slice=4))
    from abrdf_jax.select import select_model

    sel = select_model(meas)
    assert sel.name in (*aj.select.CANDIDATES, aj.select.BIVARIATE)


# ---------------------------------------------------------------------------------------------
# Through the command line


def write(folder, name, samples):
    folder.mkdir(exist_ok=True)
    io.write_samples_csv(folder / f"{name}.csv", samples)


def test_every_capture_kind_in_one_folder_call(tmp_path, iso):
    """Every capture kind of an isotropic material in one folder call: exit 0, a
    valid table each, and the model record says what was used."""
    m, ref = iso
    kinds = {
        "protocol": {},
        "dense": dict(per_slice=200),
        "jitter": dict(jitter_deg=0.5),
        "noise": dict(noise=0.02),
        "alpha": dict(alpha_deg=30.0),
        "offubo": dict(pairs=OFF_UBO),
        "extra": dict(pairs=EXTRA),
        "gap": dict(per_slice=120, gap_deg=20.0),
    }
    for k, kw in kinds.items():
        write(tmp_path / "in", k, aj.simulate_capture(m, budget="iso102", seed=3, **kw))
    out = tmp_path / "out"
    r = call_cli("reconstruct", tmp_path / "in", "-o", out, "-q", "--model", "iso", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "interpolated across the gap" in r.stderr
    record = {e["input"].split("/")[-1][:-4]: e for e in json.loads(out.with_suffix(".model.json").read_text())["inputs"]}  # fmt: skip
    errs = {}
    for k in kinds:
        table = io.read_table(out / f"{k}.npz")
        assert table.shape == (81, 81, 3) and np.isfinite(table).all()
        errs[k] = float(metrics.evaluate(table, ref)["de76"])
        used = record[k]["measurement"]
        assert used["n_used"] == used["n_samples"]
        assert used["noise_log"] is not None and used["alpha_se_deg"] >= 0
        smoothing = record[k]["smoothing"]  # the slice smoothing's noise and weight per slice
        assert len(smoothing["beta"]) == 2 * len(used["pairs"]) and smoothing["noise_log"] > 0
    assert record["offubo"]["measurement"]["pairs"] == [list(p) for p in OFF_UBO]
    assert len(record["extra"]["measurement"]["pairs"]) == 6
    assert record["gap"]["measurement"]["gaps"]
    assert errs["extra"] < errs["protocol"] and errs["dense"] < errs["protocol"]
    assert errs["jitter"] < 1.25 * errs["protocol"] and errs["noise"] < 1.1 * errs["protocol"]


def test_anisotropic_jittered_and_dense_captures_auto(tmp_path, capsys):
    """--model auto on jittered and dense anisotropic captures (the folds once failed)."""
    m = materials.get_material(ANISO)
    for k, kw in {"jitter": dict(jitter_deg=0.5), "dense": dict(per_slice=150)}.items():
        write(tmp_path / "in", k, aj.simulate_capture(m, seed=5, **kw))
    assert main(["reconstruct", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "-q"]) == 0
    doc = json.loads((tmp_path / "out.model.json").read_text())
    models = (*aj.select.CANDIDATES, aj.select.BIVARIATE)
    assert all(e["model"] in models and e["candidates"] for e in doc["inputs"])
    for k in ("jitter", "dense"):
        assert np.isfinite(io.read_table(tmp_path / "out" / f"{k}.npz")).all()


def test_a_weak_pair_is_left_out_with_a_warning(tmp_path, capsys):
    """A pair with 2 + 2 samples is a pair (>= 3 samples) too thin to interpolate: left out,
    said on the console and in the record; a pair of 2 samples is stray samples."""
    m = materials.get_material(ANISO)
    s = aj.simulate_capture(m, pairs=EXTRA, per_slice=[25, 25, 26, 26, 26, 2])
    write(tmp_path, "weak", s)
    argv = ["reconstruct", str(tmp_path / "weak.csv"), "-o", str(tmp_path / "w.npz")]
    assert main(argv + ["--model", "aniso-average"]) == 0
    err = capsys.readouterr().err
    assert "fewer than 3 diagonal samples at elevation pair(s) [[60.0, 60.0]]" in err
    used = json.loads((tmp_path / "w.model.json").read_text())["measurement"]
    assert used["weak_pairs"] == [[60.0, 60.0]] and len(used["pairs"]) == 5
    assert used["n_used"] == len(s) - 4
    s2 = aj.simulate_capture(m, budget="iso102", pairs=EXTRA, per_slice=[25, 25, 26, 26, 26, 2])
    _, rep = aj.group_slices(s2)
    assert rep["n_stray"] == 2 and rep["n_used"] == len(s2) - 2


def test_a_10000_sample_csv_is_reconstructed_in_bounded_slices(tmp_path, capsys):
    """A continuous capture of 10,000 samples: read, reduced to at most 360 knots a slice, and
    reconstructed (the slice arrays, not the sample count, set the memory)."""
    m = materials.get_material(ISO)
    s = aj.simulate_capture(m, budget="iso102", per_slice=2500, jitter_deg=0.2, noise=0.01)
    assert len(s) == 10000
    write(tmp_path, "video", s)
    samples = io.read_samples_csv(tmp_path / "video.csv")
    meas, rep = aj.group_slices(samples)
    assert meas.t.shape[-1] <= 360 and rep["n_used"] + rep["n_off_slice"] == 10000
    assert rep["n_used"] >= 9990  # a 4-sigma tolerance: a few of 10,000 may lie outside
    out = tmp_path / "v.npz"
    assert main(["reconstruct", str(tmp_path / "video.csv"), "-o", str(out), "--model", "iso"]) == 0
    assert f"{rep['n_used']} of 10000 samples" in capsys.readouterr().out
    assert np.isfinite(io.read_table(out)).all()
