"""Model selection: the isotropy test, held-out errors, the tolerance rule, the sample-count curve, the CLI."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import materials, select, tuning
from abrdf_jax.cli import main
from tests.cli_runner import assert_cli_table

CFG_A = aj.Config.recommended("aniso204")


def _noisy(meas: aj.Measurements, sigma: float, rng) -> aj.Measurements:
    y = np.asarray(meas.y) * (1.0 + sigma * rng.standard_normal(meas.y.shape))
    return aj.Measurements(
        meas.t, jnp.asarray(y, meas.y.dtype), meas.count, meas.pairs, meas.has_axial
    )


@pytest.fixture(scope="module")
def plastic():
    return aj.sample(
        materials.get_material("ggx-plastic"), CFG_A, aj.Params.default(CFG_A), as_measurements=True
    )


@pytest.fixture(scope="module")
def steel():
    return aj.sample(
        materials.get_material("ward-brushed-steel"),
        CFG_A,
        aj.Params.default(CFG_A),
        as_measurements=True,
    )


# -- the isotropy test ----------------------------------------------------------------------------


def test_chi2_survival_matches_scipy():
    stats = pytest.importorskip("scipy.stats")
    for q, dof in [(0.3, 1), (3.0, 2), (10.0, 5), (95.0, 96), (150.0, 96), (400.0, 96), (0.0, 4)]:
        np.testing.assert_allclose(
            select.chi2_sf(q, dof), stats.chi2.sf(q, dof), rtol=1e-9, atol=1e-300
        )
    # both branches (series below a + 1, continued fraction above) over the dof of real layouts
    for dof in (1, 3, 24, 97, 500, 3000):
        q = np.concatenate([[1e-9], np.linspace(0.05, 4.0 * dof + 60.0, 97)])
        want = stats.chi2.sf(q, dof)
        ok = want > 1e-290
        np.testing.assert_allclose(select.chi2_sf(q, dof)[ok], want[ok], rtol=1e-9)


def test_chi2_critical_value_is_the_level_crossing():
    from abrdf_jax.select._chi2 import chi2_critical

    stats = pytest.importorskip("scipy.stats")
    for dof in (1, 10, 96, 1000):
        for level in (0.001, 0.01, 0.5):
            crit = chi2_critical(level, dof)
            np.testing.assert_allclose(crit, stats.chi2.isf(level, dof), rtol=1e-10)
            assert (
                select.chi2_sf(crit * (1 + 1e-9), dof)
                < level
                <= select.chi2_sf(crit * (1 - 1e-9), dof)
            )
    with pytest.raises(ValueError, match="level"):
        chi2_critical(1.5, 10)


@pytest.mark.parametrize("sigma", [0.0, 0.03])
def test_isotropy_decision_on_clear_cases(plastic, steel, sigma, rng):
    iso = select.isotropy_test(_noisy(plastic, sigma, rng) if sigma else plastic)
    aniso = select.isotropy_test(_noisy(steel, sigma, rng) if sigma else steel)
    assert iso.measured and iso.isotropic, iso.reason
    assert aniso.measured and not aniso.isotropic, aniso.reason
    assert aniso.p_value < select.LEVEL and aniso.effect >= select.MIN_EFFECT
    assert aniso.statistic > 10 * max(iso.statistic, 1e-3)
    if sigma:  # the estimated noise is of the order of the true (log ≈ relative) noise
        assert 0.4 * sigma < iso.noise < 2.5 * sigma, iso.noise


def test_batched_isotropy_tests_are_the_single_tests():
    """``isotropy_tests`` (a folder's files, one pass per layout) gives every measurement the
    report it gets alone, with the noise estimated or given, with and without the estimates at
    hand, for layouts with and without axial slices mixed in one call."""
    from abrdf_jax._grouping import group_arrays
    from abrdf_jax.select._isotropy import estimate_noise_many, isotropy_tests

    names = materials.material_names()
    meas = []
    for k, name in enumerate(names * 2):
        budget = "aniso204" if k % 3 else "iso102"
        s = aj.simulate_capture(materials.get_material(name), budget=budget, noise=0.02, seed=k)
        meas.append(group_arrays(s.to_numpy(), None)[0])
    estimates = estimate_noise_many(meas, slices="axial")
    for noise, est in ((None, None), (None, estimates), (0.03, None)):
        got = isotropy_tests(meas, noise=noise, estimates=est)
        for k, (m, rep) in enumerate(zip(meas, got)):
            one = select.isotropy_test(m, noise=noise, estimate=None if est is None else est[k])
            assert rep.to_dict() == one.to_dict(), (k, noise)
    assert {r.measured for r in got} == {True, False}
    assert {r.isotropic for r in got if r.measured} == {True, False}
    # a plan given the report lists the candidates of a plan that tests itself
    from abrdf_jax.select._choice import plan

    for m, rep in zip(meas, got):
        args = (m, 15.0, "auto", None, 0.03, select.LEVEL, select.MIN_EFFECT)
        assert list(plan(*args, report=rep).configs) == list(plan(*args).configs)
        assert plan(*args, report=rep).report.to_dict() == plan(*args).report.to_dict()


def test_isotropy_statistic_by_hand(rng):
    """Constant diagonal slices; axial slices with known log deviations and a given noise σ."""
    S, n, sigma = 8, 20, 0.05
    t = np.tile(np.arange(n) * 2 * np.pi / n, (S, 1))
    dev = rng.normal(0.0, 0.04, (4, n))  # log deviations of the 4 axial slices
    y = np.ones((S, n, 3))
    y[0::2] = np.exp(dev)[..., None]
    meas = aj.Measurements(jnp.asarray(t), jnp.asarray(y), jnp.full(S, n), aj.Config().pairs, True)
    rep = select.isotropy_test(meas, noise=sigma, log_eps=1e-12)
    r = dev - dev.mean(axis=1, keepdims=True)
    q = np.sum(r**2) / sigma**2
    np.testing.assert_allclose(rep.statistic, q / (4 * (n - 1)), rtol=1e-6)
    np.testing.assert_allclose(rep.p_value, select.chi2_sf(q, 4 * (n - 1)), rtol=1e-6)
    np.testing.assert_allclose(
        rep.effect, np.sqrt(max(np.sum(r**2) - 4 * (n - 1) * sigma**2, 0) / (4 * n)), rtol=1e-6
    )
    # A larger given noise explains the same variation: isotropic.
    assert select.isotropy_test(meas, noise=0.5).isotropic
    # Without axial slices there is nothing to test.
    iso102 = aj.Measurements(meas.t, meas.y, jnp.asarray([0, n] * 4), meas.pairs, False)
    rep = select.isotropy_test(iso102)
    assert rep.isotropic and not rep.measured and rep.dof == 0


def test_noise_estimate_recovers_sigma(rng):
    n, sigma = 200, 0.05
    t = np.tile(np.arange(n) * 2 * np.pi / n, (8, 1))
    smooth = 1.0 + 0.5 * np.cos(t)  # a smooth slice: its interpolation error is far below σ
    y = (smooth * (1 + sigma * rng.standard_normal(t.shape)))[..., None].repeat(3, -1)
    meas = aj.Measurements(jnp.asarray(t), jnp.asarray(y), jnp.full(8, n), aj.Config().pairs, True)
    assert abs(select.estimate_noise(meas, log_eps=1e-12) / sigma - 1) < 0.15


# -- the tolerance rule -----------------------------------------------------------------------------


def test_tolerance_rule_picks_the_simplest_within_tol():
    errors = {"a": 1.00, "b": 1.04, "c": 1.20, "d": float("nan"), "e": 1.049}
    ranks = {"a": 3, "b": 1, "c": 0, "d": -1, "e": 1}
    assert (
        select.tolerance_choice(errors, ranks, 0.05)[0] == "b"
    )  # rank 1, the lower error of the tie
    assert select.tolerance_choice(errors, ranks, 0.0)[0] == "a"  # no tolerance: the best
    assert (
        select.tolerance_choice(errors, ranks, 0.25)[0] == "c"
    )  # the simplest with a finite error
    name, reason = select.tolerance_choice(errors, ranks, 0.01)
    assert name == "a" and "worse" in reason
    with pytest.raises(aj.InputError, match="finite"):
        select.tolerance_choice({"a": float("nan")}, {"a": 0})
    with pytest.raises(aj.InputError, match="tol"):
        select.tolerance_choice(errors, ranks, -0.1)


# -- held-out errors -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def steel_errors(steel):
    """Held-out errors of the default anisotropic candidates (the compile select_model reuses)."""
    return select.held_out_errors(
        steel, {n: select.CANDIDATES[n].config() for n in select.DEFAULT_ANISO}, k=4
    )


def test_held_out_error_equals_selfcalibration_sample_folds(steel, steel_errors):
    """One stacked solve gives SelfCalibration(folds='samples')'s loss (its definition, not a copy)."""
    cfg = select.CANDIDATES["aniso-crossing"].config()
    prob, data, params = tuning.SelfCalibration.from_samples(
        steel, cfg, aj.Params.default(cfg), folds="samples", k=4
    )
    loss = tuning.held_out_loss(prob, data, params)
    err = steel_errors["aniso-crossing"]
    n_valid = int(np.sum(np.asarray(data["test_mask"])))
    n_total = int(np.prod(data["test_mask"].shape)) * 3
    np.testing.assert_allclose(0.5 * err**2 * 3 * n_valid / n_total, loss, rtol=1e-6)


def test_select_model(plastic, steel, steel_errors):
    sel = select.select_model(steel)
    # Anisotropic by the test on the axial slices; the model is then the held-out evidence's
    # (brushed steel's diagonal-only model predicts its held-out samples as well as any).
    assert not sel.isotropy.isotropic
    assert sel.errors == pytest.approx(steel_errors, rel=1e-12) and all(
        np.isfinite(list(sel.errors.values()))
    )
    # The tolerance rule on the reported errors gives the reported choice (among anisotropic
    # candidates iso is the RBF's diagonal-only model, not the bivariate one).
    assert sel.name == select.tolerance_choice(sel.errors, sel.ranks, sel.tol)[0]
    metal = select.select_model(
        aj.sample(materials.get_material("ggx-aniso-metal"), CFG_A, as_measurements=True)
    )
    assert metal.config.budget == "aniso204" and not metal.isotropy.isotropic
    assert metal.errors["iso"] > (1 + metal.tol) * min(metal.errors.values())  # it matters here
    iso = select.select_model(plastic)  # isotropic: the bivariate model on all 8 slices
    assert iso.name == "bivariate" and iso.isotropy.isotropic and iso.config.budget == "aniso204"
    assert select.select_model(plastic, candidates="kernels").name in select.KERNEL_FAMILY
    forced = select.select_model(plastic, budget="iso102", candidates=("iso",))
    assert forced.isotropy is None and forced.name == "iso"
    with pytest.raises(aj.InputError, match="unknown model"):
        select.select_model(plastic, candidates=("nope",))


# -- how few samples -----------------------------------------------------------------------------


def test_sample_count_curve_matches_direct_sampling():
    pairs = ((30.0, 30.0), (75.0, 75.0))  # off the protocol: Config.slice_count sets the counts
    mat = materials.get_material("ggx-plastic")
    ref = materials.dense_table(mat, np.float64)
    cfg = aj.Config.recommended("iso102", pairs=pairs)
    curve = select.sample_count_curve(mat, counts=(8, 16), config=cfg, target=1e9)
    assert curve.counts == (8, 16) and curve.totals == (16, 32) and curve.needed == 8
    for n, err in zip(curve.counts[:1], curve.errors[:1]):  # one direct oracle (one more compile)
        c = aj.Config.recommended("iso102", pairs=pairs, slice_count=n)
        p = aj.Params.default(c)
        rec = aj.reconstruct(aj.sample(mat, c, p, as_measurements=True), c, p)
        np.testing.assert_allclose(err, float(aj.metrics.evaluate(rec, ref)["de76"]), rtol=1e-5)
    tight = select.sample_count_curve(
        mat, counts=(8, 16), config=cfg, target=min(curve.errors) * 0.5
    )
    assert tight.needed is None


def test_sample_count_curve_from_a_measurement(plastic):
    curve = select.sample_count_curve(plastic, counts=(12, 40))  # each count is one compile
    assert curve.counts == (12,) and curve.metric == "held_out"  # 40 is above the measured 25-26
    assert curve.totals == (12 * 8,) and all(np.isfinite(curve.errors))
    with pytest.raises(aj.InputError, match="held_out"):
        select.sample_count_curve(plastic, metric="de76")


# -- command line ----------------------------------------------------------------------------------


def test_cli_model_auto_and_fixed(tmp_path, capsys):
    meas = tmp_path / "steel.csv"
    # strongly anisotropic: the held-out errors pick an anisotropic model
    assert main(["sample", "ggx-aniso-metal", "-o", str(meas)]) == 0  # aniso204 by default
    out = tmp_path / "rec.npz"
    assert main(["reconstruct", str(meas), "-o", str(out)]) == 0  # --model auto is the default
    text = capsys.readouterr().out
    doc = json.loads((tmp_path / "rec.model.json").read_text())
    assert doc["format"] == "abrdf_jax.model/1" and doc["how"] == "auto"
    assert doc["model"] in select.DEFAULT_ANISO and doc["config"]["budget"] == "aniso204"
    assert {c["name"] for c in doc["candidates"]} == set(select.DEFAULT_ANISO)
    assert doc["isotropy"]["isotropic"] is False and doc["isotropy"]["statistic"] > 1
    assert doc["reason"] in text and "held-out log RMS" in text
    cfg = select.CANDIDATES[doc["model"]].config()
    samples = aj.io.read_samples_csv(meas)
    params = aj.Params.default(cfg, alpha_deg=doc["params"]["alpha_deg"])
    assert_cli_table(aj.io.read_table(out), samples, cfg, params)
    assert doc["engine"] == ("operator" if doc["model"] != "aniso" else "pipeline")

    # --model iso forces the diagonal-only model on the same anisotropic data.
    out_iso = tmp_path / "iso.npz"
    assert main(["reconstruct", str(meas), "-o", str(out_iso), "--model", "iso"]) == 0
    doc = json.loads((tmp_path / "iso.model.json").read_text())
    assert doc["model"] == "iso" and doc["how"] == "fixed" and doc["config"]["budget"] == "iso102"
    assert "iso102" in capsys.readouterr().out
    cfg = select.CANDIDATES["iso"].config()
    params = aj.Params.default(cfg, alpha_deg=doc["params"]["alpha_deg"])
    assert_cli_table(aj.io.read_table(out_iso), samples, cfg, params)

    # Bad choices fail before any work, naming the problem; nothing is written.
    bad = tmp_path / "bad.npz"
    for argv, match in (
        (["--model", "nope"], "unknown model 'nope'"),
        (["--model", "aniso", "--isotropic"], "--isotropic"),
        (["--model", "iso", "--params", str(meas)], "both fix the model"),
    ):
        assert main(["reconstruct", str(meas), "-o", str(bad), *argv]) == 2
        assert match in capsys.readouterr().err
    assert not bad.exists() and not (tmp_path / "bad.model.json").exists()


def test_select_models_batches_the_folds_with_the_same_choices():
    """Many materials at once: the held-out folds of one layout in one vmapped call (padded to
    select._batch.BATCH), the same choices and errors as one by one (float32 rounding)."""
    from abrdf_jax.select import _batch

    names = ("ward-brushed-steel", "ggx-aniso-metal", "ggx-plastic", "ashikhmin-satin")
    meas = [
        aj.group_slices(aj.simulate_capture(materials.get_material(n), noise=0.01, seed=i))[0]
        for i, n in enumerate(names * 5)  # 20: one full batch of 16 and one padded one
    ]
    done = []
    many = select.select_models(meas, on_done=done.append)
    assert sum(done) == len(meas) and len(many) == len(meas)
    for m, s in zip(meas, many):
        one = select.select_model(m)
        assert s.name == one.name and s.isotropy.isotropic == one.isotropy.isotropic
        assert set(s.errors) == set(one.errors)
        for n, e in one.errors.items():
            assert s.errors[n] == pytest.approx(e, rel=1e-4, nan_ok=True)
    assert _batch.BATCH < len(meas)
