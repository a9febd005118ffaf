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
