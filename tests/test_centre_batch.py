"""The restored subspaces at the RBF centres of many slice sets at once
(``abrdf_jax._centre_batch``): the one-row function's values bit for bit, on layouts with
missing slices, coincident knots, queries on knots, one-sample slices and several α."""

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import materials
from abrdf_jax._centre_batch import centre_subspaces_many
from abrdf_jax._grid import centre_count
from abrdf_jax._rules import AFFINE
from abrdf_jax._subspace import centre_subspaces

PAIRS = ((30.0, 30.0), (30.0, 75.0), (75.0, 30.0), (75.0, 75.0))


def _rows(rng, r=5, s=8, nmax=12, c=3):
    """Random padded slices: sorted knots in [0, 2π) (some coincident, some on the queries'
    angles), counts from 0 to nmax (0 and 1 included), values of both signs."""
    t = np.sort(rng.uniform(0, 2 * np.pi, (r, s, nmax)), axis=-1)
    t[0, 1, 3] = t[0, 1, 2]  # coincident knots: the interval of zero width
    t[1, 0, :4] = np.deg2rad([0.0, 15.0, 90.0, 195.0])  # knots where queries fall
    t[1, 0] = np.sort(t[1, 0])
    count = rng.integers(0, nmax + 1, (r, s))
    count[2, 2], count[3, 3], count[4, 0] = 0, 1, 0  # a missing slice, a one-sample slice
    y = rng.normal(0.0, 1.0, (r, s, nmax, c))
    valid = np.arange(nmax) < count[..., None]
    t = np.where(valid, t, 0.0)
    y = np.where(valid[..., None], y, 0.0)
    alpha = np.deg2rad(rng.uniform(10.0, 20.0, r))
    alpha[1] = np.deg2rad(15.0)
    return t, y, count, alpha


@pytest.mark.parametrize("azimuths", [None, 24])
def test_every_row_equals_the_one_row_function(rng, azimuths):
    t, y, count, alpha = _rows(rng)
    rules = tuple(AFFINE)  # filip2012 (the slices' extremes), average, crossing, diagonal
    got = centre_subspaces_many(t, y, count, PAIRS, azimuths, alpha, rules)
    assert got.shape == (len(t), len(rules), centre_count(PAIRS, azimuths), 3)
    for r in range(len(t)):
        want = centre_subspaces(
            t[r], y[r], count[r], PAIRS, azimuths, alpha[r], rules, "linear", xp=np
        )
        np.testing.assert_array_equal(got[r], want)


def test_a_measured_capture_equals_the_one_row_function():
    """The layout model selection reads: a jittered capture's grouped slices in float64."""
    s = aj.simulate_capture(materials.get_material("ggx-aniso-metal"), jitter_deg=0.5, seed=3)
    meas, info = aj.group_slices(s, dtype=np.float64)
    t, y, count = (np.asarray(v, np.float64) for v in (meas.t, meas.y, meas.count))
    count = count.astype(np.int64)
    alpha = np.deg2rad(info["alpha_deg"])
    rules = ("filip2012", "crossing")
    got = centre_subspaces_many(t[None], y[None], count[None], meas.pairs, None, [alpha], rules)
    want = centre_subspaces(t, y, count, meas.pairs, None, alpha, rules, "linear", xp=np)
    np.testing.assert_array_equal(got[0], want)
