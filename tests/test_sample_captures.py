"""Simulated real captures: ``abrdf_jax.simulate_capture`` and ``abrdf-jax sample``'s capture flags.

The API: sample counts, the statistics of the positional jitter (recorded at the true angles) and of
the value noise, the gap (exactly the near-retro samples are missing), reproducible seeds, and an
``InputError`` for every bad argument. The command line: a dense jittered noisy capture and one
at other elevation pairs, MERL files (``main`` in this process, ``cli_runner.call_cli``), one
clean failure naming the flag for every bad value (subprocesses, as a user runs it), and for a
table source (a table is known only on the UBO grid).
"""

import os

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io
from abrdf_jax.materials import get_material
from tests.cli_runner import call_cli, run_cli

SEED = int(os.environ.get("ABRDF_TEST_SEED", "0"))
ALPHA = 15.0


@pytest.fixture(scope="module")
def model():
    return get_material("ggx-aniso-metal")


def angles(s):
    return np.stack(
        [np.asarray(getattr(s, k)) for k in ("theta_i", "phi_i", "theta_v", "phi_v")], 1
    )


def wrap(deg):
    """Angles in degrees wrapped to [-180, 180)."""
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


def separation(s):
    """Angle in degrees between the light and view directions of every sample."""
    rad = np.deg2rad(angles(s))
    wi = np.asarray(aj.to_vector(rad[:, 0], rad[:, 1]))
    wv = np.asarray(aj.to_vector(rad[:, 2], rad[:, 3]))
    return np.rad2deg(np.arccos(np.clip(np.sum(wi * wv, 1), -1, 1)))


# ---------------------------------------------------------------------------------------------
# The API
# ---------------------------------------------------------------------------------------------


def test_counts(model):
    assert len(aj.simulate_capture(model)) == 204  # the protocol: 25, 25, 26, 26 per slice
    assert len(aj.simulate_capture(model, budget="iso102")) == 102
    assert len(aj.simulate_capture(model, per_slice=100)) == 800
    assert len(aj.simulate_capture(model, per_slice=1000, budget="iso102")) == 4000
    s = aj.simulate_capture(model, per_slice=[10, 20, 30, 40])
    assert len(s) == 200
    pairs = np.stack([s.theta_i, s.theta_v], 1)
    for (ti, tv), n in zip(aj.PROTOCOL_PAIRS, (10, 20, 30, 40)):
        assert np.sum(np.all(pairs == (ti, tv), axis=1)) == 2 * n
    six = [(35, 35), (35, 70), (70, 35), (70, 70), (45, 45), (60, 60)]
    s = aj.simulate_capture(model, pairs=six, per_slice=12, alpha_deg=30.0)
    assert len(s) == 6 * 2 * 12
    assert {(float(a), float(b)) for a, b in zip(s.theta_i, s.theta_v)} == set(six)
    # exact angles without jitter: the axial slices keep phi_v = phi_i - alpha
    axial = np.isclose(wrap(np.asarray(s.phi_i) - np.asarray(s.phi_v) - 30.0), 0, atol=1e-9)
    assert axial.sum() >= 6 * 12
    assert np.all(np.isfinite(np.asarray(s.rgb))) and np.all(np.asarray(s.rgb) >= 0)


def test_jitter_statistics(model):
    sigma, n = 0.5, 500
    clean = aj.simulate_capture(model, per_slice=n)
    s = aj.simulate_capture(model, per_slice=n, jitter_deg=sigma, seed=SEED)
    assert len(s) == len(clean) == 8 * n
    dev = angles(s) - angles(clean)
    dev[:, [1, 3]] = wrap(dev[:, [1, 3]])
    # every angle deviates by N(0, sigma) (elevations 30 and 75 are far from the clip at 0/89.5)
    assert np.allclose(np.std(dev, axis=0), sigma, rtol=0.08), (SEED, np.std(dev, axis=0))
    assert np.all(np.abs(np.mean(dev, axis=0)) < 4 * sigma / np.sqrt(len(s))), SEED
    # the axial slices' residual phi_i - phi_v - alpha is the difference of two errors: sqrt(2) sigma
    axial = np.isclose(wrap(angles(clean)[:, 1] - angles(clean)[:, 3] - ALPHA), 0, atol=1e-9)
    resid = wrap(np.asarray(s.phi_i) - np.asarray(s.phi_v) - ALPHA)[axial]
    assert axial.sum() >= 4 * n
    assert np.isclose(np.std(resid), np.sqrt(2) * sigma, rtol=0.1), (SEED, np.std(resid))
    # the values are those at the true (deviated) directions, not at the nominal ones
    rad = np.deg2rad(angles(s))
    wi, wv = aj.to_vector(rad[:, 0], rad[:, 1]), aj.to_vector(rad[:, 2], rad[:, 3])
    truth = np.asarray(model(np.asarray(wi, np.float32), np.asarray(wv, np.float32)))
    assert np.allclose(np.asarray(s.rgb), truth, rtol=1e-5, atol=1e-7)
    assert not np.allclose(np.asarray(s.rgb), np.asarray(clean.rgb), rtol=1e-3)


def test_noise_statistics(model):
    level = 0.05
    clean = aj.simulate_capture(model, per_slice=200)
    s = aj.simulate_capture(model, per_slice=200, noise=level, seed=SEED)
    assert np.array_equal(angles(s), angles(clean))  # noise leaves the angles alone
    ok = np.asarray(clean.rgb) > 1e-6
    rel = (np.asarray(s.rgb) / np.where(ok, np.asarray(clean.rgb), 1) - 1)[ok]
    assert np.isclose(np.std(rel), level, rtol=0.05), (SEED, np.std(rel))
    assert abs(np.mean(rel)) < 4 * level / np.sqrt(rel.size), SEED


def test_gap_removes_exactly_the_near_retro_samples(model):
    gap = 20.0
    for budget in ("iso102", "aniso204"):
        full = aj.simulate_capture(model, per_slice=120, budget=budget)
        s = aj.simulate_capture(model, per_slice=120, budget=budget, gap_deg=gap)
        near = separation(full) < gap
        assert 0 < near.sum() < len(full), budget
        assert len(s) == len(full) - near.sum(), budget
        assert np.array_equal(angles(s), angles(full)[~near]), budget
        assert np.array_equal(np.asarray(s.rgb), np.asarray(full.rgb)[~near]), budget
        assert np.all(separation(s) >= gap - 1e-3), budget
    # only the pairs with equal elevations come near the retro direction
    assert set(zip(full.theta_i[near], full.theta_v[near])) == {(30.0, 30.0), (75.0, 75.0)}


def test_seeds_are_reproducible(model):
    kw = dict(per_slice=50, jitter_deg=0.5, noise=0.02)
    a = aj.simulate_capture(model, seed=7, **kw)
    b = aj.simulate_capture(model, seed=7, **kw)
    c = aj.simulate_capture(model, seed=8, **kw)
    assert np.array_equal(angles(a), angles(b)) and np.array_equal(a.rgb, b.rgb)
    assert not np.allclose(angles(a), angles(c))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"jitter_deg": -0.1}, "jitter_deg"),
        ({"jitter_deg": float("nan")}, "jitter_deg"),
        ({"noise": -0.01}, "noise"),
        ({"noise": float("inf")}, "noise"),
        ({"gap_deg": float("nan")}, "gap_deg"),
        ({"pairs": [(30, 90)]}, "elevations"),
        ({"pairs": [(-5, 30)]}, "elevations"),
        ({"per_slice": 0}, "per_slice"),
        ({"per_slice": 2.5}, "per_slice"),
        ({"per_slice": [10, 20]}, "per_slice"),
        ({"budget": "iso"}, "budget"),
    ],
)
def test_bad_arguments_raise(model, kwargs, name):
    with pytest.raises(aj.InputError, match=name):
        aj.simulate_capture(model, **kwargs)


# ---------------------------------------------------------------------------------------------
# The command line
# ---------------------------------------------------------------------------------------------


def test_cli_capture_flags(tmp_path, model):
    proc = call_cli(
        "sample",
        "ggx-aniso-metal",
        "-o",
        "dense.csv",
        "--per-slice",
        "100",
        "--jitter",
        "0.5",
        "--noise",
        "0.02",
        "--seed",
        "3",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert "800 samples (aniso204" in proc.stdout and "--jitter 0.5" in proc.stdout
    got = io.read_samples_csv(tmp_path / "dense.csv")
    want = aj.simulate_capture(model, per_slice=100, jitter_deg=0.5, noise=0.02, seed=3)
    # the same capture (the command computes the slice angles in float32, this one in float64)
    assert np.allclose(angles(got), angles(want), atol=1e-4)
    assert np.allclose(np.asarray(got.rgb), np.asarray(want.rgb), rtol=1e-3, atol=1e-7)
    # other pairs, one count per pair, another alpha and a gap, isotropic budget
    args = ["--pairs", "35/35,35/70,70/35,70/70", "--per-slice", "30,30,40,40", "--alpha", "30"]
    proc = call_cli(
        "sample", "ggx-plastic", "-o", "iso.csv", *args, "--gap", "20", "--budget", "iso102",
        cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    want = aj.simulate_capture(
        get_material("ggx-plastic"),
        pairs=[(35, 35), (35, 70), (70, 35), (70, 70)],
        per_slice=[30, 30, 40, 40],
        alpha_deg=30.0,
        gap_deg=20.0,
        budget="iso102",
    )
    got = io.read_samples_csv(tmp_path / "iso.csv")
    assert len(got) == len(want) < 140 and np.allclose(angles(got), angles(want), atol=1e-4)
    assert f"{140 - len(want)} samples in the gap left out" in proc.stdout


def test_cli_capture_of_a_merl_file(tmp_path):
    rho = np.array([0.2, 0.4, 0.6])
    io.write_merl_binary(tmp_path / "lambert.binary", np.broadcast_to(rho / np.pi, io.MERL_SHAPE))
    proc = call_cli(
        "sample", "lambert.binary", "-o", "m.csv", "--per-slice", "40", "--jitter", "0.25",
        cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    s = io.read_samples_csv(tmp_path / "m.csv")
    assert len(s) == 160  # MERL data are isotropic: iso102's diagonal slices
    cos_i = np.cos(np.deg2rad(np.asarray(s.theta_i)))
    assert np.allclose(np.asarray(s.rgb), rho / np.pi * cos_i[:, None], rtol=1e-5)


BAD = [
    (["--per-slice", "0"], "--per-slice"),
    (["--per-slice", "ten"], "--per-slice"),
    (["--per-slice", "10,20"], "--per-slice"),  # 2 counts for the protocol's 4 pairs
    (["--pairs", "30/30,30/75", "--per-slice", "5,5,5"], "--per-slice"),
    (["--pairs", "30/90"], "--pairs"),
    (["--pairs=-1/30"], "--pairs"),
    (["--pairs", "nan/30"], "--pairs"),
    (["--pairs", "30-30"], "--pairs"),
    (["--pairs", "30/30/30"], "--pairs"),
    (["--pairs", "a/b"], "--pairs"),
    (["--pairs", "30/30,30/30"], "--pairs"),
    (["--jitter=-0.5"], "--jitter"),
    (["--jitter", "nan"], "--jitter"),
    (["--noise=-0.01"], "--noise"),
    (["--noise", "inf"], "--noise"),
    (["--noise", "two"], "--noise"),
    (["--gap=-1"], "--gap"),
    (["--gap", "nan"], "--gap"),
    (["--seed=-1"], "--seed"),
    (["--seed", "1.5"], "--seed"),
    (["--per-slice", "50", "--alpha", "nan"], "--alpha"),
]


@pytest.mark.parametrize("flags, name", BAD, ids=[" ".join(f) for f, _ in BAD])
def test_cli_bad_capture_values(tmp_path, flags, name):
    proc = run_cli("sample", "ggx-plastic", "-o", "m.csv", *flags, cwd=tmp_path)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    # checked while parsing (argparse's "error: argument NAME: ...") or right after it
    named = f"abrdf-jax: error: {name}" in proc.stderr or f"error: argument {name}:" in proc.stderr
    assert "Traceback" not in proc.stderr and named, proc.stderr
    assert not (tmp_path / "m.csv").exists()


def test_cli_table_source_refuses_capture_flags(tmp_path):
    io.write_table(tmp_path / "t.npz", np.full((81, 81, 3), 0.1, np.float32))
    for flags in (["--jitter", "0.5"], ["--per-slice", "100"], ["--seed", "2"]):
        proc = call_cli("sample", "t.npz", "-o", "m.csv", *flags, cwd=tmp_path)
        assert proc.returncode == 2, proc.stderr
        assert f"abrdf-jax: error: {flags[0]}: t.npz is a table" in proc.stderr, proc.stderr
        assert not (tmp_path / "m.csv").exists()
    proc = call_cli("sample", "t.npz", "-o", "m.csv", cwd=tmp_path)  # without them: as before
    assert proc.returncode == 0 and len(io.read_samples_csv(tmp_path / "m.csv")) == 204
