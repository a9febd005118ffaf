"""The spike cap (``abrdf_jax._spikes``, ``Config.spike_cap``): one sample that caught a narrow
specular peak must not spread across elevations, and the measured value stays where it was."""

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import tuning
from abrdf_jax._grid import _centre_target_index, ubo_grid
from abrdf_jax._spikes import cap_samples

CONST = 0.2


@pytest.fixture(scope="module")
def spiked():
    """An iso102 capture of a constant table with one diagonal sample of 30/30 raised 1000x."""
    cfg = aj.preset("recommended", "iso102")
    meas = aj.sample(np.full((81, 81, 3), CONST, np.float32), cfg, as_measurements=True)
    y = np.asarray(meas.y).copy()
    y[1, 7] *= 1000.0  # slice 1: the diagonal slice of the first pair (30/30)
    return cfg, meas.replace(y=y)


def _tables(cfg, meas):
    capped = np.asarray(aj.reconstruct(meas, cfg))
    plain = np.asarray(aj.reconstruct(meas, aj.preset("recommended", "iso102", spike_cap=None)))
    return capped, plain


def test_a_caught_spike_stays_local(spiked):
    cfg, meas = spiked
    capped, plain = _tables(cfg, meas)
    theta = ubo_grid()[0]
    far = np.ix_(np.isin(theta, (45.0, 60.0)), np.isin(theta, (45.0, 60.0)))
    # without the cap the spike reaches the unmeasured rings (2.6x the constant at worst, 19 % on
    # average); with it the RBF sees at most x1.65 of the 93 % quantile (0.10 and 1.1 % here)
    dev_plain, dev_capped = (np.abs(t[far] / CONST - 1) for t in (plain, capped))
    assert dev_plain.max() > 1.0 and dev_plain.mean() > 0.1
    assert dev_capped.max() < 0.2 and dev_capped.mean() < 0.02
    # where the restored subspaces go back (grid pairs of the centres) nothing changes
    _, dst = _centre_target_index(meas.pairs, meas.centre_azimuths)
    flat_c, flat_p = capped.reshape(-1, 3)[dst], plain.reshape(-1, 3)[dst]
    np.testing.assert_allclose(flat_c, flat_p, rtol=1e-4)
    assert flat_c.max() > 10 * CONST  # the measured peak itself is kept


def test_operator_and_numpy_entry_apply_the_cap(spiked):
    """The compiled operator (M · cap(z) + kept-row correction) and its numpy form equal the
    pipeline on the spiked capture."""
    from abrdf_jax._cache import build_entry

    cfg, meas = spiked
    params = aj.Params.default(cfg)
    expected = np.asarray(aj.reconstruct(meas, cfg, params))
    op = aj.compile_operator(cfg, params, meas)
    tol = 2e-3 * expected.max()
    np.testing.assert_allclose(np.asarray(op(meas)), expected, rtol=0, atol=tol)
    entry = build_entry(meas, cfg, params)
    assert entry.spike_cap == cfg.spike_cap and entry.keep.size > 0
    np.testing.assert_allclose(entry.apply(np.asarray(meas.y)), expected, rtol=0, atol=tol)


def test_kept_columns_finds_each_rows_nonzeros():
    from abrdf_jax._kept_rows import kept_columns

    m = np.zeros((5, 12), np.float32)
    m[1, [2, 7]] = 1.0
    m[3, [0]] = 2.0
    cols = kept_columns(m, np.array([1, 3]))
    assert cols.shape == (2, 2) and cols.dtype == np.int32
    assert cols[0].tolist() == [2, 7] and cols[1, 0] == 0 and m[3, cols[1, 1]] == 0  # pad: a zero
    assert kept_columns(m, np.array([], int)) is None
    m[1] = 1.0  # a dense kept row: the dense product
    assert kept_columns(m, np.array([1, 3])) is None


def test_sparse_kept_rows_equal_the_dense_product(spiked):
    """The kept rows' product as a sum of gathered columns (what ``compile_operator`` sets up:
    each kept row of the recommended iso102 matrix reads a few samples) equals the dense
    ``M[keep] · z``, with the spike and for a batch above the tile size."""
    import equinox as eqx
    import jax.numpy as jnp

    from abrdf_jax._operator import TILE

    cfg, meas = spiked
    op = aj.compile_operator(cfg, aj.Params.default(cfg), meas)
    assert op.keep_columns is not None and op.keep_columns.shape[1] <= 8
    dense = eqx.tree_at(lambda o: o.keep_columns, op, replace=None)
    assert dense.keep_columns is None
    rng = np.random.default_rng(0)
    y = np.asarray(meas.y)[None] * rng.uniform(0.5, 2.0, (TILE + 5, 1, 1, 3)).astype(np.float32)
    y[3, 1, 7] *= 50.0  # a second spike, elsewhere in the batch
    a, b = np.asarray(op(jnp.asarray(y))), np.asarray(dense(jnp.asarray(y)))
    np.testing.assert_allclose(a, b, rtol=1e-5)
    _, dst = _centre_target_index(meas.pairs, meas.centre_azimuths)
    assert a.reshape(len(y), -1, 3)[3, dst].max() > 100 * CONST  # the kept peak: uncapped


def test_cap_samples_masked_equals_compact():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(3, 10, 2)).astype(np.float32)
    mask = np.zeros((3, 10), bool)
    mask[:, :7] = True
    z[~mask] = 99.0  # padding must not enter the quantile
    got = np.asarray(cap_samples(z, (0.9, 0.1), mask))
    compact = np.asarray(cap_samples(z[mask].reshape(1, -1, 2), (0.9, 0.1)))
    np.testing.assert_allclose(got[mask].reshape(1, -1, 2), compact, rtol=1e-6)
    level = np.quantile(z[mask], 0.9, axis=0) + 0.1
    np.testing.assert_allclose(got[mask], np.minimum(z[mask], level), rtol=1e-6)


@pytest.mark.parametrize(
    "bad", [(0.0, 0.5), (1.5, 0.5), (0.9, -1.0), (0.9,), "high", (np.nan, 0.5)]
)
def test_bad_spike_cap_is_refused(bad):
    with pytest.raises(aj.InputError, match="spike_cap"):
        aj.Config(spike_cap=bad)


def test_spike_cap_survives_a_parameter_file(tmp_path):
    for cap in (None, (0.9, 0.25)):
        cfg = aj.preset("recommended", "iso102", spike_cap=cap)
        path = tuning.save_params(tmp_path / "p.json", cfg, aj.Params.default(cfg))
        assert tuning.load_params(path)[0].spike_cap == cap


@pytest.mark.parametrize("n", [1, 2, 7, 26, 102, 204, 400])
@pytest.mark.parametrize("q", [0.0, 0.5, 0.93, 0.99, 1.0])
def test_upper_quantile_equals_jnp_quantile(n, q):
    """The selection quantile of the compiled operator's cap (passes of max-and-remove, ties
    counted) is ``jnp.quantile``'s linear quantile, also with ties and a NaN; past
    ``SELECT_PASSES`` it is ``jnp.quantile`` itself."""
    import jax.numpy as jnp

    from abrdf_jax._spikes import upper_quantile

    rng = np.random.default_rng(n)
    z = rng.normal(size=(4, n, 3)).astype(np.float32)
    z[1] = np.round(z[1] * 2) / 2  # ties
    z[2, :, 0] = 0.25  # all equal
    z[3, 0, 2] = np.nan
    got = np.asarray(upper_quantile(jnp.asarray(z), q))
    want = np.asarray(jnp.quantile(jnp.asarray(z), q, axis=-2, keepdims=True))
    assert got.shape == want.shape == (4, 1, 3)
    assert np.isnan(got[3, 0, 2]) and np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=4 * np.finfo(np.float32).eps * 4)
