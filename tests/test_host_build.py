"""The operator store's build in numpy (``abrdf_jax._host_build``) against the JAX build
(``_operator.operator_matrix``, float64): the same matrix to float64 rounding for every linear
setting and every kind of layout, the same guard, the same refusals; ``build_entry`` uses it."""

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import materials
from abrdf_jax._cache import build_entry, x64_scope
from abrdf_jax._config import default_values
from abrdf_jax._host_build import host_matrix
from abrdf_jax._operator import operator_matrix
from abrdf_jax._rbf import fit_rbf_info
from abrdf_jax._rbf_system import host_solve, prepared

ISO, ANISO = "ggx-plastic", "ggx-aniso-metal"


def _jax_matrix(config, values, meas):
    with x64_scope(True):
        built = operator_matrix(config, values, meas, build_dtype="float64")
        return built, np.asarray(built.matrix)


def _protocol(config, name):
    return aj.sample(materials.get_material(name), config, as_measurements=True)


def _capture(name, **kw):
    return aj.group_slices(aj.simulate_capture(materials.get_material(name), **kw))[0]


CASES = {
    "iso102 recommended": (dict(preset="recommended", budget="iso102"), ISO, None),
    "iso102 paper": (dict(preset="paper", budget="iso102"), ISO, None),
    "iso102 gaussian (Cholesky)": (dict(preset="recommended", budget="iso102", kernel="gaussian"), ISO, None),
    "iso102 multiquadric halfdiff": (
        dict(preset="recommended", budget="iso102", kernel="multiquadric", parameterization="halfdiff"),
        ISO,
        None,
    ),
    "iso102 cubic slices, spherical, linear values": (
        dict(preset="paper", budget="iso102", interp="cubic", parameterization="spherical"),
        ISO,
        None,
    ),
    "aniso204 crossing": (dict(preset="recommended", budget="aniso204", rule="crossing"), ANISO, None),
    "aniso204 average": (dict(preset="operator", budget="aniso204", rule="average"), ANISO, None),
    "jittered capture": (dict(preset="recommended", budget="aniso204", rule="crossing"), ANISO,
                         dict(jitter_deg=0.5, seed=3)),
    "dense capture": (dict(preset="recommended", budget="iso102"), ISO,
                      dict(budget="iso102", per_slice=200, seed=1)),
    "off the UBO rings, six pairs": (dict(preset="recommended", budget="iso102"), ISO,
                                     dict(budget="iso102", pairs=((20, 20), (20, 70), (70, 20), (70, 70), (40, 40), (50, 60)))),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_host_build_equals_the_jax_build(case):
    kw, name, capture = CASES[case]
    preset, budget = kw.pop("preset"), kw.pop("budget")
    config = aj.preset(preset, budget, **kw)
    kw.update(preset=preset, budget=budget)  # CASES stay as they were for a rerun
    meas = _protocol(config, name) if capture is None else _capture(name, **capture)
    values = default_values(config, dtype="float64")
    host = host_matrix(config, values, meas)
    built, want = _jax_matrix(config, values, meas)
    assert host.matrix.shape == want.shape and host.matrix.dtype == np.float64
    # halfdiff: θh = arccos(h_z) at the pole is sqrt of the rounding (1.5e-8 in float64)
    tol = 1e-7 if "halfdiff" in case else 1e-9
    np.testing.assert_allclose(host.matrix, want, rtol=0, atol=tol * np.abs(want).max())
    for a, b in zip(host[1:], built[1:]):  # index, keep, stage, t, count
        np.testing.assert_array_equal(a, b)


def test_host_guard_raises_lambda_where_the_jax_guard_does():
    """A Gaussian system singular to working precision (wide kernel, λ = 0): both solvers
    raise λ to the guard's λ₁ and fit the values alike; a well-posed one is solved at λ."""
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1, 1, (60, 4)), rng.normal(size=(60, 2))
    for width, lam, retried in ((50.0, 0.0, True), (0.7, 1e-6, False)):
        deg, w, shift, scale, (k, p, s) = prepared(x, np.full(4, width), "gaussian", None, np)
        c_host, _, lam_host = host_solve(k, p, s, lam, y)
        with x64_scope(True):
            rbf, info = fit_rbf_info(x, y, np.full(4, width), "gaussian", lam)
            c_jax = np.asarray(rbf.coeffs)
        assert int(info.retries) == int(retried) and lam_host == pytest.approx(
            float(info.reg), 1e-12
        )
        assert (lam_host > lam) == retried
        # both solve the system at that λ (its coefficients, ~1e11 when raised, are not
        # determined beyond rounding: a backward-stable residual ‖A‖ ‖c‖ ε ~ 1e-3)
        a = k + lam_host * np.eye(len(x))
        for c in (c_host, c_jax):
            assert np.abs(a @ c - y).max() < (1e-2 if retried else 1e-9)


def test_a_system_singular_after_the_guard_is_an_error_on_the_host():
    """Two equal tail columns: the saddle-point system is singular whatever λ."""
    k, p = np.eye(5), np.ones((5, 2))
    with pytest.raises(np.linalg.LinAlgError):
        host_solve(k, p, 1.0, 0.0, np.ones((5, 1)))


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(budget="aniso204"), "not linear"),  # the recommended aniso204 rule is filip2012
        (dict(budget="iso102", value_space="log"), "takes the log after"),
    ],
)
def test_nonlinear_settings_are_refused_as_by_compile_operator(kw, match):
    config = aj.preset("recommended", **kw)
    meas = _protocol(config, ANISO)
    with pytest.raises(aj.InputError, match=match):
        host_matrix(config, default_values(config, dtype="float64"), meas)
    with pytest.raises(aj.InputError, match=match):
        _jax_matrix(config, default_values(config, dtype="float64"), meas)


def test_build_entry_is_the_host_build_rounded_once():
    config = aj.preset("recommended", "iso102")
    meas = _protocol(config, ISO)
    values = default_values(config, dtype="float64")
    entry = build_entry(meas, config, values)
    want = host_matrix(config, values, meas).matrix.astype(np.float32)
    np.testing.assert_array_equal(entry.matrix, want)


@pytest.mark.parametrize(
    "rule, capture",
    [("crossing", dict(seed=2)), ("filip2012", dict(jitter_deg=0.5, seed=4))],
)
def test_host_held_out_terms_equal_the_jax_build(rule, capture):
    """The held-out fits of ``--model auto`` (``select._held_out_entry``) built in numpy equal
    ``select._select.held_out_terms`` in float64 JAX, on a protocol and a jittered layout."""
    import jax.numpy as jnp

    from abrdf_jax._grid import centre_layout
    from abrdf_jax._host_build import host_held_out_terms
    from abrdf_jax._params import Params
    from abrdf_jax.select._select import fold_data, held_out_terms

    config = aj.preset("recommended", "aniso204", rule=rule)
    meas = _capture(ANISO, **capture)
    terms, ones = host_held_out_terms(meas, config, default_values(config, 15.0, "float64"), 4)
    centres = tuple(len(a) for a, _ in centre_layout(meas.pairs, meas.centre_azimuths))
    with x64_scope(True):
        m64 = meas.replace(t=jnp.asarray(meas.t, jnp.float64), y=jnp.asarray(meas.y, jnp.float64))
        data = fold_data(m64, np.deg2rad(15.0), 4)
        params = Params.default(config, alpha_deg=15.0, dtype=jnp.float64)
        want = [np.asarray(a) for a in held_out_terms(data, config, params, centres)]
    for got, w in zip((terms, ones), want):
        assert got.shape == w.shape
        np.testing.assert_allclose(got, w, rtol=0, atol=1e-9 * np.abs(w).max())
