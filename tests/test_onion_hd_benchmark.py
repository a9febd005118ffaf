"""``benchmarks.onion_hd``'s split of the error by ring pair (the figures of docs/captures.md)."""

import numpy as np

import abrdf_jax as aj
from abrdf_jax import materials, metrics
from benchmarks.onion_hd import RINGS, _blocks, ring_matrix


def test_ring_matrix_sums_to_the_mean_and_places_each_error_in_its_ring_pair():
    ref = np.asarray(materials.dense_table(materials.get_material("ggx-plastic")), np.float32)
    th, _ = aj.ubo_grid()
    rec = ref.copy()
    light, view = th == 45.0, th == 75.0
    rec[np.ix_(light, view)] *= 1.5  # an error at (45°, 75°) only
    m = ring_matrix(rec, ref)
    assert m.shape == (len(RINGS), len(RINGS))
    np.testing.assert_allclose(m.sum(), float(metrics.delta_e76(rec, ref)), rtol=1e-5)
    a, b = RINGS.index(45.0), RINGS.index(75.0)
    assert m[a, b] > 0 and np.count_nonzero(m) == 1
    blocks = _blocks(m)
    assert blocks["measured"] == 0  # 45° is not a measured ring
    np.testing.assert_allclose(blocks["interpolated"], m.sum())


def test_weight_one_is_the_package_rule_and_a_weight_is_a_narrower_width():
    """The weight sweep passes six widths: weight 1 reproduces the default four (the extra
    coordinates' width is the four's geometric mean), and a weight w on the half-vector
    coordinates equals dividing their width by w (same kernel distances)."""
    from benchmarks.onion_hd import weighted

    cfg = aj.Config.recommended(parameterization="onion-hd")
    meas = aj.sample_model(materials.get_material("ggx-plastic"), aj.protocol_counts("iso102"),
                           np.deg2rad(15.0), cfg.pairs)  # fmt: skip
    params = aj.Params.default(cfg)
    base = np.asarray(aj.reconstruct(meas, cfg, params))
    # float32 solves of the same system from widths rounded apart: 1e-4 of the largest value
    np.testing.assert_allclose(np.asarray(aj.reconstruct(meas, cfg, weighted(params, 1.0))), base,
                               rtol=0, atol=1e-3 * base.max())  # fmt: skip
    w6 = np.asarray(weighted(params, 2.0).widths)
    gm = np.exp(np.mean(np.log(np.asarray(params.widths, np.float64))))
    np.testing.assert_allclose(w6, [*np.asarray(params.widths), gm / 2, gm / 2], rtol=1e-6)
    assert not np.allclose(np.asarray(aj.reconstruct(meas, cfg, weighted(params, 2.0))), base)
