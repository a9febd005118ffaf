"""Tuning: parameter space, gradients of the tuning losses, solvers, trace counts, parameter files."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import abrdf_jax as aj
from abrdf_jax import materials, tuning
from abrdf_jax.tuning._problems import TRACE_COUNT, AbstractProblem
from tests.cli_runner import assert_cli_table

CFG_ISO = aj.Config.recommended("iso102")


@pytest.fixture(scope="module")
def plastic_meas():
    p0 = aj.Params.default(CFG_ISO)
    return aj.sample(materials.get_material("ggx-plastic"), CFG_ISO, p0, as_measurements=True), p0


@pytest.fixture(scope="module")
def clay_meas():
    p0 = aj.Params.default(CFG_ISO)
    return aj.sample(materials.get_material("lambert-clay"), CFG_ISO, p0, as_measurements=True), p0


# -- parameter space --------------------------------------------------------------------------


def test_param_space_round_trip():
    space = tuning.ParamSpace(widths="per_dim", reg=True, alpha=True)
    p = aj.Params(jnp.deg2rad(20.0), jnp.array([0.3, 0.5, 0.7, 1.1]), jnp.asarray(1e-3))
    q = space.to_params(space.init(p), p)
    np.testing.assert_allclose(q.widths, p.widths, rtol=1e-10)
    np.testing.assert_allclose(q.reg, p.reg, rtol=1e-10)
    np.testing.assert_allclose(q.alpha_deg, 20.0, rtol=1e-8)
    shared = tuning.ParamSpace(widths="shared", reg=False)
    th = shared.init(p)
    assert set(th) == {"log_widths"} and th["log_widths"].shape == (1,)
    q = shared.to_params(th, p)
    np.testing.assert_allclose(q.widths, np.exp(np.mean(np.log(p.widths))) * np.ones(4), rtol=1e-10)
    assert float(q.reg) == float(p.reg)  # fixed parameters come from the base


def test_param_space_clips_into_bounds():
    space = tuning.ParamSpace()
    q = space.to_params(
        {"log_widths": jnp.full(4, 50.0), "log_reg": jnp.asarray(-80.0)}, aj.Params.default()
    )
    assert np.all(np.isfinite(q.widths)) and float(q.widths[0]) == pytest.approx(20.0)
    assert float(q.reg) == pytest.approx(1e-9)


def test_param_space_rejects_nonsense():
    with pytest.raises(aj.InputError, match="no free parameter"):
        tuning.ParamSpace(widths="fixed", reg=False, alpha=False)
    with pytest.raises(aj.InputError, match="alpha_bounds"):
        tuning.ParamSpace(alpha_bounds_deg=(10.0, 95.0))


# -- gradients of the tuning losses --------------------------------------------------------------


def test_selfcal_gradient_matches_finite_differences(plastic_meas):
    meas, p0 = plastic_meas
    prob, data, params = tuning.SelfCalibration.from_samples(meas, CFG_ISO, p0)
    data = dict(data, base=params)
    theta = prob.space.init(params)
    loss_d = jax.jit(prob.loss)
    loss = lambda th: loss_d(th, data)  # noqa: E731  (data as an argument: no constant folding)
    assert np.isfinite(float(loss(theta)))
    check_grads(loss, (theta,), order=1, modes=["rev"], atol=1e-4, rtol=1e-3, eps=1e-4)


def test_population_gradient_in_alpha_matches_finite_differences():
    cfg = aj.Config(budget="aniso204", rule="average")
    mat = materials.get_material("ward-brushed-steel")
    ref = jnp.asarray(materials.dense_table(mat, np.float64))[None]
    p0 = aj.Params.default(cfg)
    prob = tuning.Population(
        config=cfg, space=tuning.ParamSpace(widths="shared", reg=False, alpha=True)
    )
    # The continuous model as the source: its samples are smooth in α (a table's are piecewise
    # linear in azimuth, with kinks at the grid nodes that finite differences would straddle).
    source = jax.tree_util.tree_map(lambda x: jnp.asarray(x)[None], mat)
    data = dict(tuning.Population.make_data(source, ref, p0), base=p0)
    loss_d = jax.jit(prob.loss)
    loss = lambda th: loss_d(th, data)  # noqa: E731  (data as an argument: no constant folding)
    theta = prob.space.init(p0)
    g = jax.grad(loss)(theta)
    assert abs(float(g["alpha"])) > 0  # α moves the samples: the loss depends on it
    # The loss is piecewise smooth in α (linear slice interpolation has kinks at the sample
    # nodes, which move with α), so the finite-difference step must stay inside one piece.
    check_grads(loss, (theta,), order=1, modes=["rev"], atol=1e-3, rtol=2e-3, eps=1e-6)


# -- solvers ------------------------------------------------------------------------------------


class _Quadratic(AbstractProblem):
    """Known optimum: widths (0.5, 0.8, 1.2, 2.0), λ = 1e-3, α = 22° (residuals in log units)."""

    target: tuple = (0.5, 0.8, 1.2, 2.0, 1e-3, 22.0)

    def residuals(self, theta, data):
        p = self.space.to_params(theta, data["base"])
        t = jnp.asarray(self.target)
        return jnp.concatenate(
            [
                data["scale"] * (jnp.log(p.widths) - jnp.log(t[:4])),
                jnp.atleast_1d(jnp.log(p.reg) - jnp.log(t[4])),
                jnp.atleast_1d(p.alpha - jnp.deg2rad(t[5])),
            ]
        )


@pytest.mark.parametrize("solver", tuning.SOLVERS)
def test_each_solver_finds_a_known_optimum(solver):
    space = tuning.ParamSpace(widths="per_dim", reg=True, alpha=True)
    prob = _Quadratic(config=aj.Config(), space=space)
    p0 = aj.Params(jnp.deg2rad(15.0), jnp.full(4, 1.0), jnp.asarray(1e-2))
    res = tuning.fit(
        prob, {"scale": jnp.asarray(3.0)}, p0, solver=solver, max_steps=200, atol=1e-10, rtol=1e-10
    )
    assert res.ok, res.message
    assert res.loss_final < 1e-6 * res.loss_initial
    np.testing.assert_allclose(res.params.widths, [0.5, 0.8, 1.2, 2.0], rtol=1e-3)
    np.testing.assert_allclose(float(res.params.reg), 1e-3, rtol=1e-3)
    np.testing.assert_allclose(res.params.alpha_deg, 22.0, rtol=1e-3)
    assert 1 <= res.steps <= res.evaluations == len(res.history)


def test_a_fit_without_progress_hook_has_no_host_callback_and_the_same_result():
    """``progress=None`` (``abrdf-jax fit -q``) compiles the solve without the progress callback,
    so JAX's persistent compilation cache can keep it (a program with a host callback is never
    stored); the fit is the same, bit for bit, without the evaluation count."""
    from abrdf_jax.tuning import _fitting

    space = tuning.ParamSpace(widths="per_dim", reg=True, alpha=True)
    prob = _Quadratic(config=aj.Config(), space=space)
    p0 = aj.Params(jnp.deg2rad(15.0), jnp.full(4, 1.0), jnp.asarray(1e-2))
    data = {"scale": jnp.asarray(3.0)}
    hooked = tuning.fit(prob, data, p0, solver="bfgs", max_steps=20)
    quiet = tuning.fit(prob, data, p0, solver="bfgs", max_steps=20, progress=None)
    assert quiet.evaluations is None and quiet.history == [] and hooked.evaluations >= 1
    for a, b in zip(
        jax.tree_util.tree_leaves(hooked.theta), jax.tree_util.tree_leaves(quiet.theta)
    ):
        np.testing.assert_array_equal(a, b)
    assert quiet.loss_final == hooked.loss_final and quiet.steps == hooked.steps
    theta0 = space.init(p0)
    lo, hi = space.bounds(theta0)
    for hook, has in ((True, True), (False, False)):
        static = (prob, "bfgs", 20, 1e-4, 1e-6, hook)
        text = _fitting._solve_jit.lower(*static, theta0, dict(data, base=p0), lo, hi).as_text()
        assert ("callback" in text) == has


class _Broken(AbstractProblem):
    def residuals(self, theta, data):
        return jnp.sqrt(theta["log_widths"] - 100.0)  # NaN everywhere in the domain


def test_divergence_is_a_status_not_a_nan():
    prob = _Broken(config=aj.Config(), space=tuning.ParamSpace(widths="shared", reg=False))
    p0 = aj.Params.default()
    res = tuning.fit(prob, {}, p0, solver="lm", max_steps=5)
    assert res.status == "diverged" and not res.ok
    np.testing.assert_array_equal(res.params.widths, p0.widths)  # the starting point, never NaN


def test_a_fit_stopped_by_a_bound_says_so():
    """The optimum (widths 50) lies beyond the box (widths <= 20): the fit ends at the bound
    and its warnings name each width there, and only those."""
    space = tuning.ParamSpace(widths="per_dim", reg=True)
    prob = _Quadratic(config=aj.Config(), space=space, target=(0.5, 50.0, 1.2, 50.0, 1e-3, 15.0))
    p0 = aj.Params(jnp.deg2rad(15.0), jnp.full(4, 1.0), jnp.asarray(1e-2))
    res = tuning.fit(prob, {"scale": jnp.asarray(3.0)}, p0, solver="lbfgsb", max_steps=200)
    assert res.ok, res.message
    assert res.warnings == [
        "widths[1] = 20 at its upper bound",
        "widths[3] = 20 at its upper bound",
    ]
    assert res.summary()["warnings"] == res.warnings
    inside = tuning.fit(
        _Quadratic(config=aj.Config(), space=space), {"scale": jnp.asarray(3.0)}, p0, max_steps=200
    )
    assert inside.ok and inside.warnings == []
    low = aj.Params(jnp.deg2rad(2.0), jnp.full(4, 0.02), jnp.asarray(1e-9))
    assert tuning.ParamSpace(alpha=True).at_bounds(low) == [
        *(f"widths[{i}] = 0.02 at its lower bound" for i in range(4)),
        "reg = 1e-09 at its lower bound",
        "alpha = 2 deg at its lower bound",
    ]


class _Rising(AbstractProblem):
    """``atan(x)`` from ``x = 2``: Gauss-Newton's step ``-atan(x)(1 + x²)`` overshoots to
    ``x = -3.5``, where the loss is higher (Newton on atan diverges for ``|x| > 1.39``)."""

    def residuals(self, theta, data):
        return jnp.arctan(theta["log_widths"] + 2.0)


def test_a_fit_whose_loss_rose_keeps_the_start_and_says_so():
    prob = _Rising(config=aj.Config(), space=tuning.ParamSpace(widths="shared", reg=False))
    p0 = aj.Params(jnp.deg2rad(15.0), jnp.full(4, 1.0), jnp.asarray(1e-2))
    res = tuning.fit(prob, {}, p0, solver="gn", max_steps=2)  # step 1 evaluates the start
    assert res.warnings and res.warnings[0].startswith("the loss rose from"), res
    np.testing.assert_allclose(res.params.widths, p0.widths, rtol=1e-6)
    assert res.loss_final == res.loss_initial


def test_fit_rejects_unknown_solver():
    prob = _Quadratic(config=aj.Config(), space=tuning.ParamSpace())
    with pytest.raises(aj.InputError, match="solver"):
        tuning.fit(prob, {"scale": jnp.asarray(1.0)}, aj.Params.default(), solver="adam")


def test_population_recovers_a_known_width():
    """References made by the pipeline itself at width w* = 0.35: LM must find w* again."""
    cfg = aj.Config(budget="iso102")  # the paper's Gaussian: the width matters
    mat = materials.get_material("ggx-plastic")
    table = jnp.asarray(materials.dense_table(mat, np.float64))[None]
    p_true = aj.Params(jnp.deg2rad(15.0), jnp.full(4, 0.35), jnp.asarray(1e-3))
    meas = aj.sample(table[0], cfg, p_true, as_measurements=True)
    ref = aj.reconstruct(meas, cfg, p_true)[None]
    prob = tuning.Population(config=cfg, space=tuning.ParamSpace(widths="shared", reg=False))
    p0 = aj.Params(p_true.alpha, jnp.full(4, 0.6), p_true.reg)
    res = tuning.fit(
        prob, tuning.Population.make_data(table, ref, p0), p0, solver="lm", max_steps=30
    )
    assert res.ok and res.loss_final < 1e-3 * res.loss_initial
    np.testing.assert_allclose(res.params.widths, 0.35, rtol=1e-3)


# -- no recompilation -----------------------------------------------------------------------------


def test_new_data_and_parameters_never_retrace(plastic_meas, clay_meas):
    meas_a, p0 = plastic_meas
    meas_b, _ = clay_meas
    prob, data_a, params = tuning.SelfCalibration.from_samples(
        meas_a, CFG_ISO, p0, space=tuning.ParamSpace(widths="shared")
    )
    data_b = prob.make_data(meas_b, params)
    l_a = tuning.held_out_loss(prob, data_a, params)
    n = TRACE_COUNT["residuals"]
    other = aj.Params(params.alpha, params.widths * 1.3, params.reg * 2)
    l_b = tuning.held_out_loss(prob, data_b, other)
    assert l_a != l_b and TRACE_COUNT["residuals"] == n  # new data, new values: no new trace

    r1 = tuning.fit(prob, data_a, params, solver="bfgs", max_steps=2)
    assert r1.ok and r1.loss_final < r1.loss_initial  # self-calibration lowers the held-out error
    n = TRACE_COUNT["residuals"]
    r2 = tuning.fit(prob, data_b, other, solver="bfgs", max_steps=2)
    assert TRACE_COUNT["residuals"] == n
    assert r1.loss_final != r2.loss_final


# -- self-calibration -------------------------------------------------------------------------------


def test_selfcal_sample_folds_shapes(plastic_meas):
    meas, p0 = plastic_meas
    prob, data, params = tuning.SelfCalibration.from_samples(
        meas, CFG_ISO, p0, folds="samples", k=3
    )
    # Every measured sample is held out exactly once.
    assert int(np.sum(np.asarray(data["test_mask"]))) == meas.n_samples
    with pytest.raises(aj.InputError, match="alpha"):
        tuning.SelfCalibration(
            config=CFG_ISO, space=tuning.ParamSpace(alpha=True), pairs=meas.pairs
        )


# -- parameter files ----------------------------------------------------------------------------


def test_param_file_round_trip(tmp_path):
    cfg = aj.Config.recommended("aniso204", rule="average")
    p = aj.Params(jnp.deg2rad(17.5), jnp.array([0.2, 0.3, 0.4, 0.5]), jnp.asarray(3e-4))
    path = tuning.save_params(tmp_path / "p.json", cfg, p, fit={"solver": "lm"})
    c2, p2, meta = tuning.load_params(path)
    assert c2 == cfg and meta == {"solver": "lm"}
    np.testing.assert_allclose(p2.widths, p.widths)
    np.testing.assert_allclose(p2.alpha_deg, 17.5)


@pytest.mark.parametrize(
    "text, match",
    [
        ("{not json", r"p.json:1: not valid JSON"),
        ('{"format": "other"}', "not an abrdf_jax parameter file"),
        (
            '{"format": "abrdf_jax.params/1", "config": {"kernel": "nope"}, "params": {}}',
            r"field 'config': Config.kernel must be one of",
        ),
        (
            '{"format": "abrdf_jax.params/1", "config": {}, "params": {"alpha_deg": 15, "widths": [1, 1, 1], "reg": 0.1}}',
            r"field 'params.widths': expected a list of 4 numbers, got 3 entries",
        ),
        (
            '{"format": "abrdf_jax.params/1", "config": {}, "params": {"alpha_deg": 15, "widths": [1, 1, -1, 1], "reg": 0.1}}',
            r"field 'params.widths\[2\]': -1, expected a width > 0",
        ),
    ],
)
def test_param_file_errors_name_the_file(tmp_path, text, match):
    path = tmp_path / "p.json"
    path.write_text(text)
    with pytest.raises(aj.InputError, match=match):
        tuning.load_params(path)


def test_refuses_to_save_nan(tmp_path):
    p = aj.Params(jnp.deg2rad(15.0), jnp.array([0.2, jnp.nan, 0.4, 0.5]), jnp.asarray(1e-3))
    with pytest.raises(aj.InputError, match="non-finite"):
        tuning.save_params(tmp_path / "p.json", aj.Config(), p)
    assert not (tmp_path / "p.json").exists()


# -- command line: fit -> reconstruct --params ----------------------------------------------------------


def test_cli_fit_then_reconstruct_with_params(tmp_path, capsys):
    from abrdf_jax.cli import main

    params = tmp_path / "p.json"
    assert (
        main(
            [
                "fit",
                "population",
                "--materials",
                "ggx-plastic,ward-brushed-steel",
                "-o",
                str(params),
                "--steps",
                "2",
                "--widths",
                "shared",
                "--fixed-reg",
                "--solver",
                "bfgs",
                "-q",
            ]
        )
        == 0
    )
    d = json.loads(params.read_text())
    assert d["fit"]["mode"] == "population" and d["config"]["budget"] == "iso102"
    assert d["fit"]["materials"] == ["ggx-plastic", "ward-brushed-steel"]
    assert d["fit"]["loss_final"] <= d["fit"]["loss_initial"]
    assert isinstance(d["fit"]["warnings"], list)  # what made the result doubtful, if anything
    meas = tmp_path / "m.csv"
    assert main(["sample", "ggx-plastic", "-o", str(meas), "--budget", "iso102"]) == 0
    out = tmp_path / "r.npz"
    assert main(["reconstruct", str(meas), "-o", str(out), "--params", str(params)]) == 0
    assert "parameters from" in capsys.readouterr().out
    config, p, _ = tuning.load_params(params)
    # The file gives the model, widths and λ; α stays the measurement's own (15°: where it was sampled).
    p = aj.Params(jnp.deg2rad(jnp.asarray(15.0, p.alpha.dtype)), p.widths, p.reg)
    assert_cli_table(aj.io.read_table(out), aj.io.read_samples_csv(meas), config, p)

    # The file's budget must match the measurement's; nothing is written otherwise.
    d["config"]["budget"] = "aniso204"
    other = tmp_path / "aniso.json"
    other.write_text(json.dumps(d))
    bad = tmp_path / "bad.npz"
    assert main(["reconstruct", str(meas), "-o", str(bad), "--params", str(other)]) == 2
    assert "fitted for aniso204" in capsys.readouterr().err and not bad.exists()
    # Bad input to fit fails before any work, naming what is wrong.
    assert main(["fit", "self", str(meas), "-o", str(tmp_path / "nofolder" / "p.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert (
        main(
            ["fit", "population", "--materials", "no-such-material", "-o", str(tmp_path / "q.json")]
        )
        == 2
    )
    assert "no-such-material" in capsys.readouterr().err and not (tmp_path / "q.json").exists()


def test_cli_fit_self_writes_params(tmp_path, capsys):
    """``fit self`` on a measurement file: the CLI's planned slices reach the fit (a regression:
    the numpy slices of the command line were passed on where the fit takes the pytree)."""
    from abrdf_jax.cli import main

    meas, out = tmp_path / "m.csv", tmp_path / "own.json"
    assert main(["sample", "ggx-plastic", "-o", str(meas), "--budget", "iso102"]) == 0
    argv = ["fit", "self", str(meas), "-o", str(out), "--steps", "2", "--widths", "shared"]
    assert main([*argv, "--fixed-reg", "--solver", "bfgs"]) == 0, capsys.readouterr().err
    d = json.loads(out.read_text())
    assert d["fit"]["mode"] == "self" and d["config"]["budget"] == "iso102"
    assert d["fit"]["loss_final"] <= d["fit"]["loss_initial"]
