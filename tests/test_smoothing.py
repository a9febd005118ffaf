"""Noise-driven slice smoothing (``abrdf_jax._smoothing``, ``Config.slice_smoothing``): the noise is
estimated from the samples, the weight follows it, a clean capture is left alone, and the
pipeline, the compiled operator and the numpy operator entry agree."""

import json

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import tuning
from abrdf_jax._smoothing import SPACING_0, neighbours, smooth_slices

RULE = (2 / 3, 0.03, 0.2)
CONST = 0.2


def _slices(sigma, n=200, slices=6, seed=0):
    """Log values of ``slices`` periodic slices of ``n`` uniform samples: a smooth curve plus
    independent noise of standard deviation ``sigma``; ``(z, signal, t, count)``."""
    rng = np.random.default_rng(seed)
    t = np.tile(np.arange(n) * 2 * np.pi / n, (slices, 1))
    signal = (0.3 * np.cos(t) + 0.1 * np.sin(2 * t))[..., None].repeat(3, axis=-1)
    z = signal + sigma * rng.normal(size=signal.shape)
    return z, signal, t, np.full(slices, n)


@pytest.mark.parametrize("sigma", [0.02, 0.05, 0.1])
def test_noise_is_estimated_and_sets_the_weight(sigma):
    z, signal, t, count = _slices(sigma)
    smoothed, beta, est = smooth_slices(RULE, z, t, count, np)
    assert est == pytest.approx(sigma, rel=0.1)  # σ̂ of independent noise: σ
    beta_max, floor, scale = RULE
    q = (2 * np.pi / 200 / SPACING_0) ** 2
    noise2 = est**2 - (floor * q) ** 2
    np.testing.assert_allclose(beta, beta_max * noise2 / (noise2 + (scale * q) ** 2), rtol=1e-6)
    # one shrink of uniform samples leaves (1 − β)² + β²/2 of the noise variance
    kept = np.std(smoothed - signal) / np.std(z - signal)
    b = float(beta[0])
    assert kept == pytest.approx(np.sqrt((1 - b) ** 2 + b**2 / 2), rel=0.05)
    assert kept < 0.65  # dense slices: the rule is close to β_max = 2/3 (σ²/3)


def test_sparse_slices_need_more_noise_before_they_are_smoothed():
    """At the protocol's spacing a noise-free slice's own curvature reads as noise: the floor
    keeps it unsmoothed, and the same noise gets a smaller weight than on a dense slice."""
    z, _, t, count = _slices(0.0, n=26)
    assert np.all(smooth_slices(RULE, z, t, count, np)[1] == 0.0)
    sparse = smooth_slices(RULE, _slices(0.1, n=26)[0], *_slices(0.1, n=26)[2:], np)[1]
    dense = smooth_slices(RULE, *[_slices(0.1)[i] for i in (0, 2, 3)], np)[1]
    assert 0 < sparse.max() < 0.5 * dense.min()


def test_short_slices_and_padding_are_untouched():
    z, _, t, count = _slices(0.1, n=20, slices=3)
    count = np.array([20, 2, 12])
    z[2, 12:] = 0.0  # padding of the third slice
    out = smooth_slices(0.5, z, t, count, np)[0]
    np.testing.assert_array_equal(out[1], z[1])  # fewer than 3 samples: not a slice to smooth
    np.testing.assert_array_equal(out[2, 12:], 0.0)
    left, right, _, _, valid, slice_of = neighbours(t, count, np)  # flat slots s · 20 + k
    assert left[40] == 51 and right[51] == 40 and not valid[52:].any() and slice_of[45] == 2


@pytest.fixture(scope="module")
def noisy():
    """Protocol iso102 captures of a constant table, clean and with 10 % value noise."""
    cfg = aj.preset("recommended", "iso102", slice_smoothing=RULE)
    meas = aj.sample(np.full((81, 81, 3), CONST, np.float32), cfg, as_measurements=True)
    rng = np.random.default_rng(0)
    y = np.asarray(meas.y) * (1 + 0.1 * rng.normal(size=meas.y.shape)).astype(np.float32)
    return cfg, meas, meas.replace(y=np.where(np.asarray(meas.mask)[..., None], y, 0.0))


def test_a_noisy_capture_is_smoothed_and_a_clean_one_is_not(noisy):
    cfg, clean, meas = noisy
    off = aj.preset("recommended", "iso102", slice_smoothing=None)
    assert np.all(np.asarray(aj.slice_smoothing(clean, cfg)["beta"]) == 0)
    # the same samples go in; the two programs may round the rest differently (XLA's fusions)
    np.testing.assert_allclose(
        np.asarray(aj.reconstruct(clean, cfg)), np.asarray(aj.reconstruct(clean, off)), rtol=1e-4
    )
    report = aj.slice_smoothing(meas, cfg)
    assert report["noise_log"] == pytest.approx(0.1, rel=0.25)
    diagonal = np.asarray(report["beta"][1::2])
    assert np.all(diagonal > 0.05) and np.all(np.asarray(report["beta"][0::2]) == 0)
    err = [
        np.sqrt(np.mean((np.asarray(aj.reconstruct(meas, c)) / CONST - 1) ** 2)) for c in (cfg, off)
    ]
    assert err[0] < 0.95 * err[1]


def test_each_material_gets_its_own_weight(noisy):
    """In a batch the clean member stays unsmoothed while the noisy one is smoothed."""
    cfg, clean, meas = noisy
    batch = np.asarray(aj.reconstruct_batch(aj.stack_measurements([clean, meas]), cfg))
    for got, m in zip(batch, (clean, meas)):
        np.testing.assert_allclose(got, np.asarray(aj.reconstruct(m, cfg)), rtol=0, atol=1e-4)
    off = aj.preset("recommended", "iso102", slice_smoothing=None)
    np.testing.assert_allclose(batch[0], np.asarray(aj.reconstruct(clean, off)), rtol=0, atol=1e-4)


def test_operator_and_numpy_entry_equal_the_pipeline(noisy):
    """The same per-material weights in the compiled operator and its numpy form (a fixed
    weight takes the same path: ``_smoothing.weights``)."""
    from abrdf_jax._cache import build_entry

    cfg, _, meas = noisy
    params = aj.Params.default(cfg)
    expected = np.asarray(aj.reconstruct(meas, cfg, params))
    tol = 5e-4 * expected.max()
    op = aj.compile_operator(cfg, params, meas)
    np.testing.assert_allclose(np.asarray(op(meas)), expected, rtol=0, atol=tol)
    entry = build_entry(meas, cfg, params)
    assert entry.slice_smoothing == RULE
    np.testing.assert_allclose(entry.apply(np.asarray(meas.y)), expected, rtol=0, atol=tol)
    off = np.asarray(aj.reconstruct(meas, aj.preset("recommended", "iso102", slice_smoothing=None)))
    assert np.abs(off - expected).max() > 10 * tol  # the smoothing did change the table


@pytest.mark.parametrize(
    "bad",
    [
        -0.1,
        1.5,
        np.nan,
        True,
        "auto",
        (0.5, 0.03),
        (0.0, 0.03, 0.2),
        (0.5, -1.0, 0.2),
        (0.5, 0.03, 0.0),
    ],
)
def test_bad_smoothing_is_refused(bad, tmp_path):
    with pytest.raises(aj.InputError, match="slice_smoothing"):
        aj.Config(slice_smoothing=bad)
    good = aj.preset("recommended", "iso102")
    path = tuning.save_params(tmp_path / "p.json", good, aj.Params.default(good))
    doc = json.loads(path.read_text())
    doc["config"]["slice_smoothing"] = list(bad) if isinstance(bad, tuple) else bad
    path.write_text(json.dumps(doc))
    with pytest.raises(aj.InputError, match="p.json.*slice_smoothing"):
        tuning.load_params(path)


def test_smoothing_survives_a_parameter_file(tmp_path):
    for setting in (None, 0.3, RULE):
        cfg = aj.preset("recommended", "iso102", slice_smoothing=setting)
        path = tuning.save_params(tmp_path / "p.json", cfg, aj.Params.default(cfg))
        assert tuning.load_params(path)[0].slice_smoothing == setting


def test_a_folder_pass_equals_one_by_one():
    """The command line's per-layout passes (noise estimates, smoothing records of many files at
    once) give each file exactly what a call of its own gives."""
    from abrdf_jax._grouping import group_arrays
    from abrdf_jax._smoothing import slice_smoothing, slice_smoothings
    from abrdf_jax.select import _isotropy

    meas = []
    for i, name in enumerate(["ggx-plastic", "ggx-aniso-metal", "lambert-clay"] * 2):
        model = aj.materials.get_material(name)
        for budget in ("iso102", "aniso204"):
            s = aj.simulate_capture(model, budget=budget, noise=0.02 * (i % 3), seed=i)
            meas.append(group_arrays(s, None)[0])
    for slices in ("axial", "diagonal", "all"):
        one = [_isotropy.estimate_noise(m, slices=slices) for m in meas]
        many = _isotropy.estimate_noise_many(meas, slices=slices)
        assert many == one and all(np.isfinite(one))
    # the isotropy test given a folder's estimate reports what it reports estimating it itself
    for m, est in zip(meas, _isotropy.estimate_noise_many(meas)):
        alone = _isotropy.isotropy_test(m)  # (to_dict: a NaN statistic equals itself there)
        assert _isotropy.isotropy_test(m, estimate=est).to_dict() == alone.to_dict()
        assert alone.noise_source == "estimated"
    rec = aj.Config.recommended  # the log samples: the value space that smooths
    cfgs = [rec(), rec(slice_smoothing=CONST), rec(slice_smoothing=None)] * 4
    one = [slice_smoothing(m, c) for m, c in zip(meas, cfgs)]
    assert slice_smoothings(meas, cfgs) == one
    assert one[0]["noise_log"] is not None and one[1]["noise_log"] is None and one[2] is None


def test_per_layout_scatters_each_group_pass_back_in_order():
    """``_per_layout.per_layout``: one call per distinct key, with the positions of that key in
    order; results land at their positions, ``None`` keys get ``None`` and no call."""
    from abrdf_jax._per_layout import per_layout

    calls = []

    def run(ks):
        calls.append(ks)
        return [f"r{k}" for k in ks]

    assert per_layout(["a", None, "b", "a", "b"], run) == ["r0", None, "r2", "r3", "r4"]
    assert calls == [[0, 3], [2, 4]]
    assert per_layout([], run) == [] and per_layout([None], run) == [None]


@pytest.mark.parametrize("m", [1, 2, 5, 102, 307])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_nonneg_nanmedian_equals_jnp_nanmedian(m, dtype):
    """The sort-free median of the noise estimate (bisection on the bit patterns) equals
    ``jnp.nanmedian`` bit for bit, with NaNs, ties and an all-NaN row, and has its gradient
    (the tests run with float64 on: both dtypes)."""
    import jax
    import jax.numpy as jnp

    from abrdf_jax._smoothing import nonneg_nanmedian

    rng = np.random.default_rng(m)
    a = np.abs(rng.normal(size=(5, m))).astype(dtype)
    a[1] = np.round(a[1] * 2) / 2  # ties
    a[2, rng.random(m) < 0.4] = np.nan
    a[3] = np.nan
    a[4, 0] = 0.0
    got = np.asarray(nonneg_nanmedian(jnp.asarray(a)))
    want = np.asarray(jnp.nanmedian(jnp.asarray(a), axis=-1))
    assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True)
    b = jnp.asarray(np.abs(rng.normal(size=(3, m))).astype(dtype))  # distinct values
    np.testing.assert_array_equal(
        jax.grad(lambda v: nonneg_nanmedian(v).sum())(b),
        jax.grad(lambda v: jnp.nanmedian(v, axis=-1).sum())(b),
    )
