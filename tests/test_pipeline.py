"""The whole pipeline: shapes, invariances, batching (jit == eager and gradients: test_transforms.py)."""

import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax._slices import protocol_counts


def smooth_model(wi, wv):
    """A smooth anisotropic test material (glossy lobe around the mirror direction)."""
    r = jnp.stack([-wi[..., 0], -wi[..., 1], wi[..., 2]], -1)
    c = jnp.sum(r * wv, -1)
    lobe = jnp.exp(3.0 * (c - 1.0)) * (1.0 + 0.3 * wi[..., 0] * wv[..., 0])
    base = 0.2 + 0.5 * lobe
    out = jnp.stack([base, 0.8 * base, 0.6 * base], -1) * wi[..., 2:3]
    return jnp.where((wi[..., 2:3] > 0) & (wv[..., 2:3] > 0), out, 0.0)


def iso_model(wi, wv):
    d = jnp.sum(wi * wv, -1)
    v = 0.2 + 0.4 * jnp.exp(2.0 * (d - 1.0))
    return jnp.stack([v, v, 0.5 * v], -1) * wi[..., 2:3]


def test_protocol_budgets():
    assert sum(protocol_counts("iso102")) == 102
    assert sum(protocol_counts("aniso204")) == 204
    with pytest.raises(ValueError):
        protocol_counts("iso50")


def test_sample_then_group_round_trip():
    cfg = aj.Config(budget="aniso204")
    s = aj.sample(smooth_model, cfg)
    assert len(s) == 204
    meas, rep = aj.group_slices(s)
    assert rep["n_off_slice"] == 0 and rep["n_used"] == 204
    # the diagonal sample at the crossing φv = 0 (φi = α) also serves the axial slice
    want = list(protocol_counts("aniso204"))
    assert rep["counts"][1::2] == want[1::2]
    assert all(0 <= c - w <= 2 for c, w in zip(rep["counts"][0::2], want[0::2]))
    iso, rep_iso = aj.group_slices(aj.sample(smooth_model, aj.Config()))
    assert not iso.has_axial and rep_iso["counts"][0::2] == [0, 0, 0, 0]
    direct = aj.sample(smooth_model, cfg, as_measurements=True)
    k = 25
    np.testing.assert_allclose(meas.y[1, :k], direct.y[1, :k], rtol=1e-6)
    np.testing.assert_allclose(meas.t[3, :k], direct.t[3, :k], atol=1e-6)


def test_group_tolerates_off_slice_and_estimates_alpha():
    cfg = aj.Config(budget="iso102")
    p = aj.Params.default(cfg, alpha_deg=20.0)
    s = aj.sample(smooth_model, cfg, p)
    extra = aj.Samples(
        np.array([45.0, 30.0]),
        np.array([10.0, 33.0]),
        np.array([45.0, 30.0]),
        np.array([100.0, 70.0]),
        np.ones((2, 3)),
    )
    s2 = aj.Samples.concatenate([s, extra])
    assert abs(aj.estimate_alpha(s2) - 20.0) < 1e-6
    meas, rep = aj.group_slices(s2, alpha_deg=None)
    assert rep["n_off_slice"] == 2 and rep["n_used"] == 102
    assert abs(rep["alpha_deg"] - 20.0) < 1e-6


def test_group_without_diagonal_slices_fails():
    s = aj.Samples(
        np.array([45.0]), np.array([10.0]), np.array([45.0]), np.array([100.0]), np.ones((1, 3))
    )
    with pytest.raises(aj.InputError, match="no sample lies on a diagonal slice"):
        aj.group_slices(s)


def test_sample_table_exact_on_grid_positions():
    """With α = 0 and 24 samples the 75/75 diagonal slice lands on grid directions."""
    theta, phi = aj.ubo_grid()
    table = np.random.default_rng(0).uniform(0.1, 1.0, (81, 81, 3))
    counts = (0, 0, 0, 0, 0, 0, 0, 24)
    from abrdf_jax._sampling import sample_table

    m = sample_table(table, counts, 0.0, dtype=jnp.float64)
    ring = np.arange(57, 81)
    for k in range(24):
        pv = k * 15.0
        pi_ = (360.0 - pv) % 360.0
        i = ring[int(round(pi_ / 15.0)) % 24]
        v = ring[k]
        np.testing.assert_allclose(m.y[7, k], table[i, v], rtol=1e-12)


@pytest.mark.parametrize("budget", ["iso102", "aniso204"])
def test_reconstruct_shape_finite_nonnegative(budget):
    cfg = aj.Config(budget=budget)
    rec = aj.reconstruct(aj.sample(smooth_model, cfg), cfg)
    assert rec.shape == (81, 81, 3)
    assert np.all(np.isfinite(rec)) and np.all(rec >= 0)


def test_reconstruct_keeps_measured_subspaces_where_slices_pass_grid():
    """Budget iso102: at 30/30, the subspace value at a grid pair equals eq. (5)."""
    cfg = aj.Config()
    meas = aj.sample(iso_model, cfg, as_measurements=True)
    rec = aj.reconstruct(meas, cfg)
    # a 30/30 grid pair: i = index of (30, 0), v = index of (30, 180)
    i, v = 7, 13
    wi = aj.to_vector(np.deg2rad(30.0), 0.0)
    wv = aj.to_vector(np.deg2rad(30.0), np.pi)
    np.testing.assert_allclose(rec[i, v], iso_model(wi, wv), rtol=2e-2)


@pytest.mark.parametrize("value_space", ["linear", "log"])
def test_constant_material_stays_constant(value_space):
    cfg = aj.Config(kernel="thin_plate_spline", value_space=value_space)
    const = lambda wi, wv: jnp.full(wi.shape[:-1] + (3,), 0.4)  # noqa: E731
    rec = aj.reconstruct(aj.sample(const, cfg), cfg)
    np.testing.assert_allclose(rec, 0.4, rtol=1e-4)


def test_scaling_input_scales_output_linear_rules():
    cfg = aj.Config(budget="aniso204", rule="crossing")
    meas = aj.sample(smooth_model, cfg, as_measurements=True)
    a = aj.reconstruct(meas, cfg)
    b = aj.reconstruct(
        aj.Measurements(meas.t, 3.0 * meas.y, meas.count, meas.pairs, meas.has_axial), cfg
    )
    np.testing.assert_allclose(b, 3.0 * a, rtol=1e-9, atol=1e-12)


def test_isotropic_material_azimuth_rotation_changes_little():
    """Rotating an isotropic material's azimuths leaves the reconstruction nearly unchanged."""
    cfg = aj.Config()
    rec = aj.reconstruct(aj.sample(iso_model, cfg), cfg)
    # compare the 30° ring (illumination) rotated by one grid step against the reference view ring
    ring = np.arange(7, 19)
    a = np.asarray(rec)[np.ix_(ring, ring)]
    b = np.roll(np.roll(a, 1, 0), 1, 1)
    assert np.max(np.abs(a - b)) < 0.05 * np.max(a)


def test_batch_equals_loop():
    cfg = aj.Config()
    models = [lambda wi, wv, k=k: smooth_model(wi, wv) * (1 + 0.2 * k) + 0.01 * k for k in range(3)]
    samples = [aj.sample(m, cfg) for m in models]
    batch = aj.reconstruct_batch(samples, cfg)
    loop = jnp.stack([aj.reconstruct(s, cfg) for s in samples])
    assert batch.shape == (3, 81, 81, 3)
    # grouped Samples are float32 (the package default): batched BLAS may round differently
    np.testing.assert_allclose(batch, loop, rtol=2e-5, atol=1e-6)


def test_aniso_config_needs_axial_slices():
    s = aj.sample(smooth_model, aj.Config(budget="iso102"))
    with pytest.raises(aj.InputError, match="needs axial slices"):
        aj.reconstruct(s, aj.Config(budget="aniso204"))
    assert aj.infer_budget(s) == "iso102"
    assert aj.infer_budget(aj.sample(smooth_model, aj.Config(budget="aniso204"))) == "aniso204"


def test_config_validation():
    with pytest.raises(ValueError, match="Config.kernel"):
        aj.Config(kernel="sinc")
    with pytest.raises(ValueError, match="Config.budget"):
        aj.Config(budget="iso50")


def test_other_elevation_pairs_and_alpha():
    """Any elevation pairs (UBO rings or not) and any α: sample, group and reconstruct."""
    cfg = aj.Config(budget="aniso204", pairs=((45.0, 45.0), (20.0, 70.0)), slice_count=16)
    assert cfg.counts == (16, 16, 16, 16)
    p = aj.Params.default(cfg, alpha_deg=25.0)
    s = aj.sample(smooth_model, cfg, p)
    assert len(s) == 64
    meas, rep = aj.group_slices(s, alpha_deg=None, pairs=cfg.pairs)
    assert abs(rep["alpha_deg"] - 25.0) < 1e-4 and rep["n_off_slice"] == 0
    rec = aj.reconstruct(meas, cfg, p)
    assert rec.shape == (81, 81, 3) and np.all(np.isfinite(rec))
    with pytest.raises(ValueError, match="Config.pairs"):
        aj.Config(pairs=((95.0, 30.0),))
