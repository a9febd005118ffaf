"""Tests of the PROTOCOL.md metrics: colour-science and numpy oracles, hand cases, invariances, gradients."""

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from abrdf_jax import metrics as M
from abrdf_jax._errors import InputError
from abrdf_jax.metrics._metrics import _de2000_pairs

de2000_pairs = jax.jit(_de2000_pairs)

# One table shape for every test, so that evaluate / evaluate_batch compile once (per dtype).
SHAPE = (81, 81, 3)

SCALAR_METRICS = {
    "rmse8": M.rmse8,
    "psnr": M.psnr,
    "de76": M.delta_e76,
    "de2000": M.delta_e2000,
    "logerr": M.log_error,
}

# colour-science's sRGB colourspace uses the 4-digit IEC matrix by default; the package derives the
# matrix from the primaries, which is colour-science's "derived" matrix.
SRGB_DERIVED = colour.RGB_COLOURSPACES["sRGB"].copy()
SRGB_DERIVED.use_derived_transformation_matrices(True)


# ------------------------------------------------------------------------------------------------
# An independent numpy + colour-science implementation of the protocol (the oracle).


@jax.jit
def _all_metrics_jit(rec, ref):
    """Every scalar metric function, jitted together (one compilation)."""
    return {k: f(rec, ref) for k, f in SCALAR_METRICS.items()}


def _np_exposure(ref):
    Y = ref.reshape(-1, 3) @ np.array([0.2126, 0.7152, 0.0722])
    ym = np.median(Y)
    if ym <= 0:
        ym = np.mean(Y)
    return 0.18 / ym if ym > 0 else 1.0


def _colour_lab(t):
    xyz = colour.RGB_to_XYZ(
        t, SRGB_DERIVED, illuminant=SRGB_DERIVED.whitepoint, apply_cctf_decoding=False
    )
    return colour.XYZ_to_Lab(xyz, illuminant=np.array([0.3127, 0.3290]))


def _np_metrics(rec, ref):
    e = _np_exposure(ref)
    y_rec, y_ref = np.maximum(rec * e, 0.0), np.maximum(ref * e, 0.0)
    t_rec, t_ref = y_rec / (1 + y_rec), y_ref / (1 + y_ref)
    q_rec = 255 * colour.cctf_encoding(t_rec, "sRGB")
    q_ref = 255 * colour.cctf_encoding(t_ref, "sRGB")
    rmse = np.sqrt(np.mean((q_rec - q_ref) ** 2))
    lab_rec, lab_ref = _colour_lab(t_rec), _colour_lab(t_ref)
    return {
        "rmse8": rmse,
        "psnr": 20 * np.log10(255 / rmse) if rmse > 0 else np.inf,
        "de76": np.mean(colour.delta_E(lab_rec, lab_ref, method="CIE 1976")),
        "de2000": np.mean(colour.delta_E(lab_rec, lab_ref, method="CIE 2000")),
        "logerr": np.mean(np.abs(np.log1p(y_rec) - np.log1p(y_ref))),
    }


def _random_pair(rng, shape=None, extremes=True):
    """A positive random reference and a perturbed reconstruction, with zeros and huge values."""
    shape = SHAPE if shape is None else shape
    ref = rng.lognormal(-2.0, 1.5, shape)
    rec = ref * rng.lognormal(0.0, 0.5, shape) + rng.normal(0.0, 0.01, shape)
    if extremes:
        flat_rec, flat_ref = rec.reshape(-1, 3), ref.reshape(-1, 3)
        flat_ref[:5] = 0.0  # black pairs in ref
        flat_rec[3:8] = 0.0  # black pairs in rec (overlapping)
        flat_rec[10:13] = 1e6  # huge values
        flat_ref[12:15] = 1e8
        flat_rec[20:23] = -0.3  # negative values count as 0
        flat_ref[30:33] = 0.25  # exactly neutral pairs
    return rec, ref


# ------------------------------------------------------------------------------------------------
# Constants and the building blocks.


def test_matrix_is_colour_sciences_derived_matrix():
    npm = colour.normalised_primary_matrix(SRGB_DERIVED.primaries, SRGB_DERIVED.whitepoint)
    np.testing.assert_allclose(M.SRGB_TO_XYZ, npm, rtol=0, atol=1e-15)
    # RGB white maps to the Lab white: L* = 100, a* = b* = 0
    np.testing.assert_allclose(M.srgb_to_lab(jnp.ones(3)), [100.0, 0.0, 0.0], atol=1e-12)
    # the rounded IEC constants differ at the 1e-4 level only
    np.testing.assert_allclose(
        M.SRGB_TO_XYZ, colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, atol=1e-4
    )


def test_srgb_encode_matches_colour(rng):
    t = np.concatenate([[0.0, 0.0031308, 0.0031309, 1.0, 1e-9], rng.uniform(0, 1, 500)])
    np.testing.assert_allclose(
        M.srgb_encode(t), colour.cctf_encoding(t, "sRGB"), rtol=1e-13, atol=1e-15
    )


def test_lab_matches_colour(rng):
    t = np.concatenate(
        [np.zeros((1, 3)), rng.uniform(0, 1, (500, 3)), rng.uniform(0, 1e-3, (50, 3))]
    )
    np.testing.assert_allclose(M.srgb_to_lab(t), _colour_lab(t), rtol=1e-10, atol=1e-10)


def test_tonemap():
    y = jnp.array([-1.0, 0.0, 1.0, 3.0, 1e12])
    np.testing.assert_allclose(M.tonemap(y), [0.0, 0.0, 0.5, 0.75, 1.0], rtol=1e-12)


def test_de2000_sharma_published_pairs():
    # Sharma, Wu & Dalal (2005), test data table (4-decimal published values).
    pairs = [
        ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
        ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
        ((50.0, 2.49, -0.001), (50.0, -2.49, 0.0009), 7.1792),
        ((50.0, -0.001, 2.49), (50.0, 0.0009, -2.49), 4.8045),
        ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
        ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
    ]
    lab1 = jnp.array([p[0] for p in pairs])
    lab2 = jnp.array([p[1] for p in pairs])
    np.testing.assert_allclose(de2000_pairs(lab1, lab2), [p[2] for p in pairs], atol=5e-5)
    np.testing.assert_allclose(de2000_pairs(lab2, lab1), [p[2] for p in pairs], atol=5e-5)


def test_de2000_matches_colour_on_lab(rng):
    lab1 = np.column_stack([rng.uniform(0, 100, 2000), rng.normal(0, 40, (2000, 2))])
    lab2 = lab1 + rng.normal(0, 10, lab1.shape)
    lab2[:50] = lab1[:50]  # identical
    lab1[50:100, 1:] = 0.0  # neutral
    expected = colour.delta_E(lab1, lab2, method="CIE 2000")
    np.testing.assert_allclose(
        de2000_pairs(jnp.asarray(lab1), jnp.asarray(lab2)), expected, atol=1e-9
    )


# ------------------------------------------------------------------------------------------------
# Exposure.


def test_expose_median_and_fallbacks():
    ref = np.zeros((5, 3))
    ref[:, 1] = [1.0, 2.0, 3.0, 4.0, 5.0]  # Y = 0.7152 * G, median G = 3
    np.testing.assert_allclose(M.expose(ref), 0.18 / (0.7152 * 3.0), rtol=1e-14)
    ref = np.zeros((5, 3))
    ref[0] = 1.0  # median 0 -> mean of Y = 1/5
    np.testing.assert_allclose(M.expose(ref), 0.18 / 0.2, rtol=1e-12)
    assert float(M.expose(np.zeros((4, 4, 3)))) == 1.0  # median and mean 0 -> e = 1


def test_exposure_uses_reference_only(rng):
    rec, ref = _random_pair(rng, extremes=False)
    base = M.evaluate(rec, ref)
    both = M.evaluate(7.3 * rec, 7.3 * ref)
    for k in ("rmse8", "de76", "de2000", "logerr", "psnr"):
        np.testing.assert_allclose(both[k], base[k], rtol=1e-9, err_msg=k)
    rec_only = M.evaluate(2.0 * rec, ref)
    for k in ("rmse8", "de76", "de2000", "logerr"):
        assert abs(float(rec_only[k]) - float(base[k])) > 1e-3 * abs(float(base[k])), k
    # the exposure is set by ref: scaling rec does not change it
    assert float(M.expose(ref)) == float(M.expose(ref))
    np.testing.assert_allclose(M.expose(2.0 * ref), M.expose(ref) / 2.0, rtol=1e-14)


# ------------------------------------------------------------------------------------------------
# Oracles and hand cases.


@pytest.mark.parametrize("extremes", [False, True])
def test_metrics_match_numpy_colour_oracle(rng, extremes):
    rec, ref = _random_pair(rng, extremes=extremes)
    expected = _np_metrics(rec, ref)
    got = M.evaluate(rec, ref)
    for k in M.METRIC_KEYS:
        np.testing.assert_allclose(got[k], expected[k], rtol=1e-9, atol=1e-6, err_msg=k)
    for k, v in _all_metrics_jit(rec, ref).items():
        np.testing.assert_allclose(v, expected[k], rtol=1e-9, atol=1e-6, err_msg=k)


def test_identical_tables(rng):
    _, ref = _random_pair(rng)
    out = M.evaluate(ref, ref)
    for k in ("rmse8", "de76", "de2000", "logerr"):
        assert float(out[k]) == 0.0, k
    assert float(out["psnr"]) == np.inf
    assert float(M.psnr(ref, ref)) == np.inf


def test_constant_offset_by_hand():
    # ref: constant grey 0.18 -> Y = 0.18 (weights sum to 1), e = 0.18 / 0.18 = 1 up to rounding.
    ref = np.full(SHAPE, 0.18)
    rec = ref + 0.05
    e = 0.18 / np.median(ref @ np.array([0.2126, 0.7152, 0.0722]))

    def q(x):
        t = x * e / (1 + x * e)
        return 255 * (1.055 * t ** (1 / 2.4) - 0.055)  # t > 0.0031308: the power branch

    rmse = abs(q(0.23) - q(0.18))  # every value differs by the same amount
    np.testing.assert_allclose(M.rmse8(rec, ref), rmse, rtol=1e-12)
    np.testing.assert_allclose(M.psnr(rec, ref), 20 * np.log10(255 / rmse), rtol=1e-12)
    np.testing.assert_allclose(
        M.log_error(rec, ref), abs(np.log1p(0.23 * e) - np.log1p(0.18 * e)), rtol=1e-12
    )


def test_bad_shapes():
    with pytest.raises(InputError, match="same shape"):
        M.rmse8(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(InputError, match="RGB last"):
        M.evaluate(np.zeros((4, 4)), np.zeros((4, 4)))
    with pytest.raises(InputError, match="no direction pairs"):
        M.expose(np.zeros((0, 3)))
    with pytest.raises(InputError, match="empty"):
        M.summarize([])


# ------------------------------------------------------------------------------------------------
# Differentiability.


def test_gradients_finite_at_degenerate_points(rng):
    rec, ref = _random_pair(rng)
    zero = np.zeros_like(ref)
    cases = {
        "rec == ref": (ref, ref),
        "rec == 0": (zero, ref),
        "ref == 0": (rec, zero),
        "both 0": (zero, zero),
        "extremes": (rec, ref),
        "neutral rec": (np.repeat(rec[..., :1], 3, axis=-1), ref),
    }
    recs = jnp.asarray(np.stack([c[0] for c in cases.values()]))
    refs = jnp.asarray(np.stack([c[1] for c in cases.values()]))

    @jax.jit
    def all_grads(a, b):  # every metric's gradient, vmapped over the cases
        return {k: jax.vmap(jax.grad(f))(a, b) for k, f in SCALAR_METRICS.items()}

    grads = all_grads(recs, refs)
    for name, g in grads.items():
        for j, case in enumerate(cases):
            assert np.all(np.isfinite(np.asarray(g[j]))), f"{name}: non-finite gradient at {case}"
        # rec == ref is a minimum of every error: the (sub)gradient returned there is exactly 0
        assert np.all(np.asarray(g[0]) == 0.0), name


def test_check_grads_smooth(rng):
    # Away from the kinks: muted colours keep XYZ above CIELAB's (6/29)^3 and t above the sRGB
    # linear segment; rec has nearly the hue of ref, far from CIEDE2000's
    # discontinuity at a hue difference of 180 degrees (where the mean hue jumps).
    # The output is evaluate's dict of all five metrics: check_grads projects it on random
    # cotangents, so every metric's gradient is checked at once (one compilation, not five).
    ref = rng.uniform(0.5, 2.0, (*SHAPE[:-1], 1)) * rng.uniform(0.6, 1.4, SHAPE)
    # each pair brighter or darker by 10-30 % (never close to ref: the norms stay far from their kink)
    scale = np.exp(
        rng.choice([-1.0, 1.0], (*SHAPE[:-1], 1)) * rng.uniform(0.1, 0.3, (*SHAPE[:-1], 1))
    )
    rec = ref * scale * rng.uniform(0.98, 1.02, SHAPE)
    check_grads(lambda r: M.evaluate(r, ref), (rec,), order=1, modes=("rev",))


# ------------------------------------------------------------------------------------------------
# Transformations and aggregation.


def test_jit_equals_eager(rng):
    rec, ref = _random_pair(rng)
    jitted = _all_metrics_jit(rec, ref)
    for name, f in SCALAR_METRICS.items():
        np.testing.assert_allclose(jitted[name], f(rec, ref), rtol=1e-12, err_msg=name)
    np.testing.assert_allclose(jax.jit(M.expose)(ref), M.expose(ref), rtol=1e-14)


def test_evaluate_batch_equals_loop_and_summarize(rng):
    pairs = [_random_pair(rng) for _ in range(3)]
    recs = np.stack([p[0] for p in pairs])
    refs = np.stack([p[1] for p in pairs])
    batch = M.evaluate_batch(recs, refs)
    loop = [M.evaluate(a, b) for a, b in pairs]
    for k in M.METRIC_KEYS:
        assert batch[k].shape == (3,)
        np.testing.assert_allclose(batch[k], [d[k] for d in loop], rtol=1e-12, err_msg=k)
    s_batch, s_list = M.summarize(batch), M.summarize(loop)
    for k in M.METRIC_KEYS:
        np.testing.assert_allclose(s_batch[k], np.mean([float(d[k]) for d in loop]), rtol=1e-12)
        np.testing.assert_allclose(s_list[k], s_batch[k], rtol=1e-12)
    # an exact reconstruction makes the PSNR mean +inf (kept, not dropped)
    loop[0] = M.evaluate(pairs[0][1], pairs[0][1])
    assert float(M.summarize(loop)["psnr"]) == np.inf


def test_float32_smoke(rng):
    rec, ref = _random_pair(rng, extremes=False)
    out32 = M.evaluate(rec.astype(np.float32), ref.astype(np.float32))
    out64 = M.evaluate(rec, ref)
    for k in M.METRIC_KEYS:
        assert out32[k].dtype == jnp.float32, k
        np.testing.assert_allclose(out32[k], out64[k], rtol=1e-3, err_msg=k)


# ------------------------------------------------------------------------------------------------
# Real data.


def test_real_tables(data_dir):
    with np.load(data_dir / "merl-nbrdf" / "tables81.npz") as z:
        tables = z["abrdf"][[0, 37, 101]].astype(np.float64)  # three materials
    assert tables.shape[1:] == (81, 81, 3)
    same = M.evaluate_batch(tables, tables)
    for k in ("rmse8", "de76", "de2000", "logerr"):
        np.testing.assert_array_equal(same[k], 0.0)
    assert np.all(np.asarray(same["psnr"]) == np.inf)
    flat = np.broadcast_to(tables.mean(axis=(1, 2, 3), keepdims=True), tables.shape)
    out = M.evaluate_batch(flat, tables)
    for k in M.METRIC_KEYS:
        assert np.all(np.isfinite(np.asarray(out[k]))), k
    assert np.all(np.asarray(out["de76"]) > 1.0)
    assert np.all(np.asarray(out["de2000"]) > 0.0)
    summary = M.summarize(out)
    assert set(summary) == set(M.METRIC_KEYS)
