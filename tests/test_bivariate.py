"""The bivariate (θh, θd) model: oracles of the thin-plate fit, exact recovery of functions it
can represent, any capture geometry, and clear errors (abrdf_jax._bivariate)."""

from types import SimpleNamespace

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import _bivariate, _pair_residual, _tps, materials, metrics


def _points(n, seed=0):
    return np.random.default_rng(seed).uniform(0.0, 1.0, (n, 2))


def test_matrix_reproduces_degree_one_polynomials():
    """Thin-plate spline with a linear term: a linear function is fitted exactly, so each row
    of the map sums to 1 and the map carries the coordinates themselves to the targets."""
    src, dst = _points(60), _points(25, seed=1)
    m = _bivariate.bivariate_matrix(src, dst, smoothing=1e-3)
    assert m.shape == (25, 60)
    np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(m @ src, dst, atol=1e-9)


def test_matrix_interpolates_without_smoothing():
    src = _points(40)
    m = _bivariate.bivariate_matrix(src, src, smoothing=0.0)
    np.testing.assert_allclose(m, np.eye(40), atol=1e-7)


def test_binned_fit_still_reproduces_linear_functions(monkeypatch):
    """Above MAX_POINTS samples the plane is binned (cell means of coordinates and values): a
    linear function stays exact, and the map still has one column per sample."""
    monkeypatch.setattr(_tps, "MAX_POINTS", 50)
    monkeypatch.setattr(_tps, "BINS", 8)
    src, dst = _points(400), _points(30, seed=2)
    m = _bivariate.bivariate_matrix(src, dst)
    assert m.shape == (30, 400)
    f = 0.3 + 1.7 * src[:, 0] - 0.4 * src[:, 1]
    np.testing.assert_allclose(m @ f, 0.3 + 1.7 * dst[:, 0] - 0.4 * dst[:, 1], atol=1e-9)


def test_binning_bounds_the_solve(monkeypatch):
    """However spread the samples, the solve holds at most MAX_POINTS cells (coarser bins)."""
    monkeypatch.setattr(_tps, "MAX_POINTS", 40)
    src = _points(3000)  # spread over the whole plane: 128 x 128 cells would keep ~3000
    centres, which, count = _tps.binned(src)
    assert len(centres) <= 40 and which.shape == (3000,) and count.sum() == 3000
    for k in (0, len(centres) // 2, len(centres) - 1):  # each centre: the mean of its cell
        np.testing.assert_allclose(src[which == k].mean(axis=0), centres[k])


def _table_of(fn):
    """``fn(u, v)`` (the BRDF at the bivariate coordinates) times cos θi on the UBO grid."""
    wi, wv, _ = _bivariate._grid()
    uv = _bivariate.bivariate_coordinates(wi, wv)
    brdf = fn(uv[:, 0], uv[:, 1])[:, None] * np.array([1.0, 0.6, 0.3])
    return (brdf * wi[:, 2:3]).reshape(81, 81, 3)


class _Bivariate:
    """A material whose BRDF is ``exp(0.2 + 1.3 u − 0.8 v)`` at the bivariate coordinates
    ``(u, v)``: linear in the log, so the fit recovers it exactly."""

    def __call__(self, wi, wv):
        uv = _bivariate.bivariate_coordinates(np.asarray(wi), np.asarray(wv))
        brdf = np.exp(0.2 + 1.3 * uv[..., 0] - 0.8 * uv[..., 1])[..., None]
        return brdf * np.array([1.0, 0.6, 0.3]) * np.asarray(wi)[..., 2:3]


def _samples_of(fn, capture):
    wi = aj.to_vector(np.deg2rad(capture.theta_i), np.deg2rad(capture.phi_i), np)
    wv = aj.to_vector(np.deg2rad(capture.theta_v), np.deg2rad(capture.phi_v), np)
    return aj.Samples(
        capture.theta_i, capture.phi_i, capture.theta_v, capture.phi_v, np.asarray(fn(wi, wv))
    )


@pytest.mark.parametrize(
    "kind",
    [
        {},
        {"per_slice": 60},
        {"jitter_deg": 0.5, "seed": 3},
        {"pairs": ((35.0, 35.0), (35.0, 70.0), (70.0, 35.0), (70.0, 70.0))},
    ],
)
def test_recovers_a_bivariate_material_from_any_capture(kind):
    """Every capture geometry (protocol, dense, jittered, off the UBO rings): the samples are
    used at their own directions, and a material of the model's form comes back to float32
    rounding everywhere, at the pairs no slice measured too."""
    lambert = materials.get_material("lambert-clay")
    capture = aj.simulate_capture(lambert, budget="iso102", **kind)
    fn = _Bivariate()
    table = aj.reconstruct_bivariate(_samples_of(fn, capture), log_eps=1e-12)
    truth = _table_of(lambda u, v: np.exp(0.2 + 1.3 * u - 0.8 * v))
    assert table.shape == (81, 81, 3) and table.dtype == np.float32
    np.testing.assert_allclose(table, truth, rtol=2e-5, atol=1e-7)


def _azimuthal(wi, wv):
    """A material of the model's form times a factor in ``Δφ`` (and the elevations) that the
    plane of ``(θh, θd)`` cannot hold."""
    wi, wv = np.asarray(wi), np.asarray(wv)
    dphi = np.arctan2(wi[..., 1], wi[..., 0]) - np.arctan2(wv[..., 1], wv[..., 0])
    extra = np.exp(0.4 * np.cos(dphi) * np.sin(np.arccos(wi[..., 2])))[..., None]
    return _Bivariate()(wi, wv) * extra


def test_measured_pairs_keep_their_residual_curves():
    """A material that depends on ``Δφ`` beyond ``(θh, θd)``: with a dense capture the cells of
    the measured pairs come back nearly exact (the pairs' residual curves), where the spline
    alone (``pair_width=0``) misses by far more; a material of the model's form has no residual
    (the correction leaves it exact: the test above)."""
    capture = aj.simulate_capture(materials.get_material("lambert-clay"), per_slice=180)
    samples = _samples_of(_azimuthal, capture)
    wi, wv, _ = _bivariate._grid()
    truth = np.asarray(_azimuthal(wi, wv)).reshape(81, 81, 3)
    theta = aj.ubo_grid()[0]
    at = (theta[:, None] == 30.0) & (theta[None, :] == 75.0)  # a measured pair's cells
    err = {}
    for width in (0.0, _pair_residual.PAIR_WIDTH_DEG):
        table = aj.reconstruct_bivariate(samples, log_eps=1e-12, pair_width=width)
        rel = np.abs(table - truth) / truth
        err[width] = (np.max(rel[at]), np.mean(rel))
    assert err[_pair_residual.PAIR_WIDTH_DEG][0] < 0.01 < err[0.0][0] / 3
    assert err[_pair_residual.PAIR_WIDTH_DEG][1] < err[0.0][1]  # and better over the table


def test_pair_residual_matrix_interpolates_each_pairs_curve():
    """At a measured pair's own targets the correction's rows are periodic linear interpolation
    weights over ``Δφ`` of that pair's samples (a sum of ``g / max(1, Σ g)``); no width, no map."""
    capture = aj.simulate_capture(materials.get_material("lambert-clay"), budget="iso102")
    wi = aj.to_vector(np.deg2rad(capture.theta_i), np.deg2rad(capture.phi_i), np)
    wv = aj.to_vector(np.deg2rad(capture.theta_v), np.deg2rad(capture.phi_v), np)
    gi, gv, _ = _bivariate._grid()
    targets = _pair_residual.target_angles(gi, gv)
    c = _pair_residual.pair_residual_matrix(wi, wv, targets)
    assert not _pair_residual.pair_residual_matrix(wi, wv, targets, 0.0).any()
    assert c.min() >= 0 and c.sum(1).max() <= 1 + 1e-12
    # a residual that is a linear function of Δφ on one pair's samples, zero on the others
    ti, tv = np.asarray(capture.theta_i), np.asarray(capture.theta_v)
    dphi = (np.asarray(capture.phi_i) - np.asarray(capture.phi_v)) % 360
    on = (ti == 75.0) & (tv == 75.0)
    r = np.where(on, np.cos(np.deg2rad(dphi)), 0.0)
    theta, phi = aj.ubo_grid()
    cells = np.nonzero(((theta[:, None] == 75.0) & (theta[None, :] == 75.0)).reshape(-1))[0]
    q = (np.repeat(phi, 81) - np.tile(phi, 81))[cells] % 360
    d, v = np.sort(dphi[on]), np.cos(np.deg2rad(np.sort(dphi[on])))
    g = c[cells][:, on].sum(1)  # the pair's share at its cells: 1 / (1 + the others' g)
    np.testing.assert_allclose(c[cells] @ r, g * np.interp(q, d, v, period=360), atol=1e-12)
    assert 0.95 < g.min() and g.max() < 1


def test_the_spline_is_evaluated_once_per_distinct_point():
    """The grid's 6561 direction pairs have 384 distinct (θh, θd) coordinates; each pair's
    point is its own coordinates (to POINT_TOL), so the gathered evaluation is the direct one."""
    points, at, angles = _bivariate._grid_targets()
    wi, wv, _ = _bivariate._grid()
    direct = _bivariate.bivariate_coordinates(wi, wv)
    assert points.shape == (384, 2) and at.shape == (6561,) and angles.shape == (6561, 3)
    np.testing.assert_allclose(points[at], direct, rtol=0, atol=_bivariate.POINT_TOL)
    src = _points(30)
    m = _tps.basis(points, src)[at]
    np.testing.assert_allclose(m, _tps.basis(direct, src), rtol=0, atol=1e-8)


def test_one_measurement_applies_the_map_in_factors(monkeypatch):
    """``bivariate_values`` (what ``reconstruct_bivariate`` runs) equals the layout map
    ``bivariate_map`` applied to the same values, on the grid and at targets, with and without
    the residual curves and the plane binned; the table is the map's within float32 rounding."""
    capture = aj.simulate_capture(
        materials.get_material("ggx-plastic"), budget="iso102", jitter_deg=0.5, seed=3
    )
    ti, pi_, tv, pv, rgb = _bivariate._columns(capture)
    wi, wv = _bivariate.source_vectors(ti, pi_, tv, pv)
    z = _bivariate.log_brdf(rgb[None], np.cos(ti), _bivariate.LOG_EPS)[0][0]
    targets = (wi[::7], wv[::3][: len(wi[::7])])
    monkeypatch.setattr(_tps, "ROWS", 50)  # the basis in several row blocks
    for max_points in (4096, 40):  # the samples as centres; binned into at most 40 cells
        monkeypatch.setattr(_tps, "MAX_POINTS", max_points)
        for width in (0.0, _pair_residual.PAIR_WIDTH_DEG):
            for tg in (None, targets):
                m = _bivariate.bivariate_map(wi, wv, tg, pair_width=width)
                got = _bivariate.bivariate_values(wi, wv, z, tg, pair_width=width)
                np.testing.assert_allclose(got, m @ z, rtol=0, atol=1e-9)
    monkeypatch.setattr(_tps, "MAX_POINTS", 4096)
    m = _bivariate.bivariate_map(wi, wv)
    table = _bivariate._values(m, rgb[None], np.cos(ti), _bivariate._grid()[2], _bivariate.LOG_EPS)
    np.testing.assert_allclose(
        aj.reconstruct_bivariate(capture), table[0].reshape(81, 81, 3), rtol=1e-5, atol=1e-7
    )


def test_a_continuous_capture_in_bounded_memory():
    """20,000 samples (5,000 a diagonal slice): no matrix with a row per target and a column per
    sample (6561 x 20000 float64 would be 1 GB; numpy's allocations peak far below), and the
    dense capture restores the material at least as well as the protocol's 102 samples."""
    import tracemalloc

    mat = materials.get_material("ggx-plastic")
    dense = aj.simulate_capture(mat, budget="iso102", per_slice=5000, jitter_deg=0.3, seed=2)
    assert len(dense) == 20000
    tracemalloc.start()
    try:
        table = aj.reconstruct_bivariate(dense)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20, peak / 2**20
    ref = materials.dense_table(mat)
    sparse = aj.reconstruct_bivariate(aj.simulate_capture(mat, budget="iso102"))
    de = [float(metrics.evaluate(t, ref)["de76"]) for t in (table, sparse)]
    assert np.isfinite(table).all() and de[0] <= de[1], de


def test_targets_evaluate_anywhere():
    capture = aj.simulate_capture(materials.get_material("lambert-clay"), budget="iso102")
    samples = _samples_of(_Bivariate(), capture)
    rng = np.random.default_rng(5)
    v = rng.normal(size=(2, 50, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.1
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    out = aj.reconstruct_bivariate(samples, targets=(v[0], v[1]), log_eps=1e-12)
    np.testing.assert_allclose(out, _Bivariate()(v[0], v[1]), rtol=2e-5, atol=1e-7)


def test_accuracy_on_isotropic_analytic_materials():
    """A Lambertian material is a constant BRDF: exact; a GGX plastic (isotropic, nearly a
    function of θh and θd) far below the mean fill's error."""
    for name, bound in (("lambert-clay", 1e-3), ("ggx-plastic", 2.0)):
        m = materials.get_material(name)
        s = aj.simulate_capture(m, budget="iso102", seed=0)
        ref = materials.dense_table(m)
        de = float(metrics.evaluate(aj.reconstruct_bivariate(s), ref)["de76"])
        fill = np.broadcast_to(np.mean(np.asarray(s.rgb), 0), (81, 81, 3)).astype(np.float32)
        assert de < bound and de < 0.1 * float(metrics.evaluate(fill, ref)["de76"]), (name, de)


def _good():
    return aj.simulate_capture(materials.get_material("lambert-clay"), budget="iso102")


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda s: aj.reconstruct_bivariate(object()), "samples must be Samples"),
        (
            lambda s: aj.reconstruct_bivariate(
                aj.Samples(s.theta_i[:2], s.phi_i[:2], s.theta_v[:2], s.phi_v[:2], s.rgb[:2])
            ),
            "at least 3 samples",
        ),
        (  # any object with the fields (e.g. io.read_sample_columns's) is checked too
            lambda s: aj.reconstruct_bivariate(
                SimpleNamespace(
                    theta_i=s.theta_i,
                    phi_i=s.phi_i,
                    theta_v=s.theta_v,
                    phi_v=s.phi_v,
                    rgb=np.where(np.arange(len(s))[:, None] == 4, np.nan, np.asarray(s.rgb)),
                )
            ),
            "samples.rgb has non-finite",
        ),
        (lambda s: aj.reconstruct_bivariate(s, smoothing=-1.0), "smoothing must be"),
        (lambda s: aj.reconstruct_bivariate(s, log_eps=0.0), "log_eps must be"),
        (lambda s: aj.reconstruct_bivariate(s, pair_width=-1.0), "pair_width must be"),
        (
            lambda s: aj.reconstruct_bivariate(s, targets=(np.zeros((4, 3)), np.zeros((5, 3)))),
            "targets must be",
        ),
    ],
)
def test_bad_input_is_a_clear_error(call, match):
    with pytest.raises(aj.InputError, match=match):
        call(_good())


def test_command_line_model_bivariate(tmp_path):
    """``reconstruct --model bivariate``: one file and a folder (one map per layout, the same
    tables), equal to the library call on the same samples: jittered angles (0.5°), which the
    slices read at their recorded directions, not at their projections onto the slice; the
    model record says what ran; unknown models list it."""
    from abrdf_jax import io

    from tests.cli_runner import run_cli

    names = ("ggx-plastic", "lambert-clay", "ward-brushed-steel")
    folder = tmp_path / "in"
    folder.mkdir()
    expected = {}
    for k, name in enumerate(names):
        s = aj.simulate_capture(
            materials.get_material(name), budget="iso102", jitter_deg=0.5, seed=k
        )
        io.write_samples_csv(folder / f"{name}.csv", s)
        expected[name] = aj.reconstruct_bivariate(io.read_samples_csv(folder / f"{name}.csv"))
    one = run_cli(
        "reconstruct", "in/ggx-plastic.csv", "-o", "one.npz", "--model", "bivariate", cwd=tmp_path
    )
    assert one.returncode == 0, one.stderr
    assert "model: bivariate (fixed)" in one.stdout
    assert "left out" not in one.stderr  # every sample read: the library's input
    np.testing.assert_allclose(
        io.read_table(tmp_path / "one.npz"), expected["ggx-plastic"], rtol=1e-4, atol=1e-6
    )
    many = run_cli("reconstruct", "in", "-o", "out", "--model", "bivariate", "-q", cwd=tmp_path)
    assert many.returncode == 0, many.stderr
    assert "models bivariate x3" in many.stdout and "left out" not in many.stderr
    for name in names:
        table = io.read_table(tmp_path / "out" / f"{name}.npz")
        np.testing.assert_allclose(table, expected[name], rtol=1e-4, atol=1e-6)
    import json

    record = json.loads((tmp_path / "out.model.json").read_text())
    assert {e["model"] for e in record["inputs"]} == {"bivariate"}
    bad = run_cli("reconstruct", "in", "-o", "x", "--model", "bivariat", cwd=tmp_path)
    assert bad.returncode == 2 and "bivariate" in bad.stderr and not (tmp_path / "x").exists()


def test_a_layouts_map_key_holds_its_recorded_directions():
    """``BivariateModel.layout_key``: slices with the same projections but other recorded
    directions are another layout (another map); without directions it is the RBF's key; and
    the map of the same layout is built once."""
    from abrdf_jax._grouping import group_arrays, layout_key

    capture = aj.simulate_capture(materials.get_material("lambert-clay"), jitter_deg=0.5, seed=4)
    sa, _ = group_arrays(capture.to_numpy())
    moved = sa._replace(directions=sa.directions.copy())
    moved.directions[1, 0, 0] = _bivariate.to_vector(0.6, 0.1, np)  # one slot elsewhere
    model = _bivariate.BivariateModel("aniso204")
    assert model.layout_key(sa) == model.layout_key(sa._replace(y=sa.y * 2))  # values: no
    assert model.layout_key(sa) != model.layout_key(moved)
    assert model.layout_key(sa._replace(directions=None)) == layout_key(sa)
    params = SimpleNamespace(alpha=np.deg2rad(15.0))
    assert model.operator(params, sa) is model.operator(params, sa._replace(y=sa.y * 2))
    assert model.operator(params, sa) is not model.operator(params, moved)


def test_a_layout_of_one_measurement_builds_no_matrix(monkeypatch):
    """The command line's apply of one layout: a batch of one (a jittered capture, alone in its
    layout) is the map in factors and builds no matrix; a batch of two builds the layout's matrix
    once; both give the same tables within float32 rounding."""
    from abrdf_jax._grouping import group_arrays

    capture = aj.simulate_capture(materials.get_material("ggx-plastic"), jitter_deg=0.5, seed=8)
    sa, _ = group_arrays(capture.to_numpy())
    built = []
    real = _bivariate.bivariate_map
    monkeypatch.setattr(
        _bivariate, "bivariate_map", lambda *a, **k: built.append(1) or real(*a, **k)
    )
    apply = _bivariate.BivariateModel("aniso204").operator(
        SimpleNamespace(alpha=np.deg2rad(15.0)), sa
    )
    y = np.asarray(sa.y)[None]
    one = apply(y)
    assert one.shape == (1, 81, 81, 3) and one.dtype == np.float32 and not built
    two = apply(np.concatenate([y, 0.5 * y]))
    assert len(built) == 1
    np.testing.assert_allclose(two[0], one[0], rtol=1e-5, atol=1e-7 * one.max())
    np.testing.assert_allclose(two[1], apply(0.5 * y)[0], rtol=1e-5, atol=1e-7 * one.max())
    apply(np.concatenate([y, y]))
    assert len(built) == 1  # built once per layout


def test_automatic_choice_of_an_isotropic_material():
    """``select_model``: a material the isotropy test accepts gets the bivariate model on every
    slice (``aniso204``), a forced ``iso102`` budget on the diagonal slices; the selection's
    table is the library call's (Samples) and the slice map's (Measurements); an anisotropic
    material and a prior keep the RBF candidates; explicit candidates are kept."""
    from abrdf_jax import select

    cfg = aj.Config(budget="aniso204")
    mat = materials.get_material("ggx-plastic")
    samples = aj.sample(mat, cfg)
    meas = aj.sample(mat, cfg, as_measurements=True)
    sel = select.select_model(samples)
    assert sel.name == "bivariate" and sel.isotropy.isotropic and sel.config.budget == "aniso204"
    assert sel.ranks["bivariate"] < min(c.rank for c in select.CANDIDATES.values())
    assert "isotropic material" in sel.reason
    table = sel.reconstruct(samples)
    np.testing.assert_array_equal(table, aj.reconstruct_bivariate(samples))
    np.testing.assert_allclose(
        select.select_model(meas).reconstruct(meas), table, rtol=1e-4, atol=1e-6
    )
    forced = select.select_model(meas, budget="iso102")
    assert forced.name == "bivariate" and forced.config.budget == "iso102"
    iso_samples = aj.sample(mat, aj.Config(budget="iso102"))
    np.testing.assert_allclose(
        forced.reconstruct(meas), aj.reconstruct_bivariate(iso_samples), rtol=1e-4, atol=1e-6
    )
    assert select.select_model(meas, candidates=("iso",)).name == "iso"
    metal = select.select_model(
        aj.sample(materials.get_material("ggx-aniso-metal"), cfg, as_measurements=True)
    )
    assert not metal.isotropy.isotropic and metal.name in select.DEFAULT_ANISO
    from abrdf_jax.select._choice import finish, plan, with_prior

    # With a prior, iso is scored beside the learned models and stands for the isotropic ones:
    # where it wins, the bivariate model; where a learned model wins, that one.
    p = with_prior(plan(meas, 15.0, "auto", None, None, 1e-3, 0.02), fused=True)
    assert set(p.configs) == {"iso", "prior", "fused"} and set(p.stand_in) == {"iso"}
    won = finish(p, {"iso": 0.1, "prior": 0.3, "fused": 0.2}, 0.05, 4, 0.0)
    assert won.name == "bivariate" and won.config.budget == "aniso204"
    assert won.errors["iso"] == 0.1 and "stands for the isotropic models" in won.reason
    assert finish(p, {"iso": 0.3, "prior": 0.3, "fused": 0.1}, 0.05, 4, 0.0).name == "fused"
    explicit = plan(meas, 15.0, ("iso", "aniso"), "aniso204", None, 1e-3, 0.02)
    assert not explicit.stand_in  # named candidates are taken as named
    metal_meas = aj.sample(materials.get_material("ggx-aniso-metal"), cfg, as_measurements=True)
    aniso_plan = plan(metal_meas, 15.0, "auto", None, None, 1e-3, 0.02)
    assert "iso" in aniso_plan.configs and not aniso_plan.stand_in  # iso is the RBF there


def test_command_line_auto_is_bivariate_for_isotropic_files(tmp_path):
    """``reconstruct`` (``--model auto``) of an isotropic file: the bivariate model, the same
    table as ``--model bivariate``, the record says it was chosen and why."""
    import json

    from abrdf_jax import io

    from tests.cli_runner import run_cli

    s = aj.simulate_capture(materials.get_material("ggx-plastic"), budget="iso102", seed=3)
    io.write_samples_csv(tmp_path / "m.csv", s)
    auto = run_cli("reconstruct", "m.csv", "-o", "auto.npz", cwd=tmp_path)
    assert auto.returncode == 0, auto.stderr
    fixed = run_cli("reconstruct", "m.csv", "-o", "fixed.npz", "--model", "bivariate", cwd=tmp_path)
    assert fixed.returncode == 0, fixed.stderr
    np.testing.assert_array_equal(
        io.read_table(tmp_path / "auto.npz"), io.read_table(tmp_path / "fixed.npz")
    )
    doc = json.loads((tmp_path / "auto.model.json").read_text())
    assert doc["model"] == "bivariate" and doc["how"] == "auto"
    assert doc["config"]["budget"] == "iso102" and "isotropic" in doc["reason"]
    assert [c["name"] for c in doc["candidates"]] == ["iso"]  # scored for the isotropic models
    assert "stands for the isotropic models" in doc["reason"] and doc["rank"] == -1


def test_benchmark_smoke(tmp_path, data_dir):
    """``python -m benchmarks.bivariate --quick``: the train sweep, both splits and the analytic
    set, each kind's RBF (one CLI folder call) and bivariate figures, the report and the chart
    (figures of a smoke run are not checked against values: the full run is the measurement)."""
    import json

    from benchmarks import bivariate

    bivariate.main(["--quick", "--out", str(tmp_path)], log=lambda *a: None)
    payload = json.loads((tmp_path / "bivariate_quick.json").read_text())
    assert set(payload["sets"]) == {"merl-train", "merl-test", "analytic"}
    assert len(payload["sets"]["merl-train"]["sweep"]) == 9
    for block in payload["sets"].values():
        for r in block["kinds"].values():
            for method in ("rbf", "bivariate"):
                assert set(r[method]["per_material"]) == set(block["materials"])
                assert np.isfinite(r[method]["de76"]) and r[method]["de76"] > 0
            assert set(r["bivariate_better"]) <= set(block["materials"])
    md = (tmp_path / "bivariate_quick.md").read_text()
    assert "## merl-test" in md and "log_eps" in md
    assert (tmp_path / "bivariate_quick.png").stat().st_size > 10_000
