"""The prior's basis at the exact sample directions (abrdf_jax.prior._exact, ``sample_basis``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import abrdf_jax as aj
from abrdf_jax import prior as P
from abrdf_jax._sampling import table_corners

F64 = jnp.float64
#: A small recipe of the default prior's kind (12 analytic materials, 4 components).
RECIPE = {**P.DEFAULT_RECIPE, "n": 12, "k": 4}


@pytest.fixture(scope="module")
def prior():
    from abrdf_jax.prior._default import build_default_prior

    return build_default_prior(RECIPE).astype(F64)


def _layout(alpha_deg=15.0):
    cfg = aj.Config(budget="iso102")
    p = aj.Params.default(cfg, alpha_deg=alpha_deg, dtype=F64)
    return aj.sample(aj.materials.get_material("ggx-plastic"), cfg, p, as_measurements=True)


def test_the_training_models_are_the_training_tables(prior):
    """The recipe read back from the prior's (sorted JSON) metadata draws the same materials,
    and at the grid directions they are the tables the prior was trained on."""
    models = P.training_models(prior)
    assert models is not None and models.n == RECIPE["n"]
    ti, pi, tv, pv = (np.deg2rad(np.asarray(a, np.float64)) for a in aj.pair_grid())
    wi = np.stack([np.sin(ti) * np.cos(pi), np.sin(ti) * np.sin(pi), np.cos(ti)], -1)
    wv = np.stack([np.sin(tv) * np.cos(pv), np.sin(tv) * np.sin(pv), np.cos(tv)], -1)
    values = np.asarray(models(jnp.asarray(wi), jnp.asarray(wv)))
    tables, _ = P.default_training_tables(RECIPE)
    np.testing.assert_allclose(values, tables.reshape(RECIPE["n"], -1, 3), rtol=1e-6, atol=1e-9)


def test_exact_basis_is_the_grid_basis_at_grid_pairs_and_the_numpy_one_everywhere(prior):
    meas = _layout()
    alpha = jnp.deg2rad(15.0)
    exact = P.sample_basis(prior, meas, alpha)
    s, n = meas.t.shape
    valid = np.asarray(meas.mask).reshape(-1)
    # Where a sample lies on a grid pair, the components are the prior's own there.
    i0, i1, v0, v1, a, b = (
        np.asarray(x).reshape(-1) for x in table_corners(meas.t, alpha, meas.pairs)
    )
    at0 = valid & (np.minimum(a, 1 - a) < 1e-9) & (np.minimum(b, 1 - b) < 1e-9)
    assert at0.sum() >= 2
    row = np.where(a < 0.5, i0, i1) * 81 + np.where(b < 0.5, v0, v1)
    comps = np.asarray(exact.components)
    np.testing.assert_allclose(
        comps[at0], np.asarray(prior.components)[row[at0]], rtol=1e-5, atol=1e-5
    )
    np.testing.assert_allclose(
        np.asarray(exact.mean)[at0], np.asarray(prior.mean)[row[at0]], atol=1e-5
    )
    # Everywhere: the numpy form of the same combination (basis_from_training).
    models = P.training_models(prior)
    wi, wv = aj.slice_directions(meas.t, meas.pairs, alpha)
    x_s = np.array(models(wi.reshape(-1, 3), wv.reshape(-1, 3)))
    x_s[:, ~valid] = 1.0
    tv = np.repeat([meas.pairs[i // 2][1] for i in range(s)], n)
    pca = P.PCA(None, None, np.asarray(prior.weights), None, 0)
    ref = P.basis_from_training(
        pca, x_s, np.cos(np.deg2rad(tv)), valid, channels=prior.channels, eps=prior.eps, dtype=F64
    )
    for name in ("mean", "reference", "components"):
        got, want = np.asarray(getattr(exact, name))[valid], np.asarray(getattr(ref, name))[valid]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, err_msg=name)
    assert np.array_equal(np.asarray(exact.weight), valid.astype(float))


def test_differentiable_in_alpha(prior):
    meas = _layout(13.3)

    def f(alpha):
        b = P.sample_basis(prior, meas, alpha)
        return jnp.sum(b.components[:, 0] * b.weight) + jnp.sum(b.mean * b.weight)

    # a small step: the reference is a median, piecewise in α (a wide step may cross a switch)
    check_grads(jax.jit(f), (jnp.deg2rad(13.3),), order=1, modes=["rev"], eps=1e-6)


def test_a_prior_without_models_interpolates_its_grid(prior, rng):
    meas = _layout()
    without = prior.__class__(
        prior.mean, prior.components, prior.reference, prior.lam,
        eps=prior.eps, channels=prior.channels, meta=prior.meta,
    )  # fmt: skip
    assert P.training_models(without) is None
    a, b = P.sample_basis(without, meas), P.prior_at_samples(without, meas)
    assert np.array_equal(np.asarray(a.components), np.asarray(b.components))


def test_weights_round_trip_and_a_bad_shape_is_rejected(prior, tmp_path):
    path = P.save_prior(prior.astype(jnp.float32), tmp_path / "p.npz")
    back = P.load_prior(path)
    assert np.array_equal(np.asarray(back.weights), np.asarray(prior.weights, np.float32))
    assert P.training_models(back) is not None
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["weights"] = arrays["weights"][:, :2]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(aj.InputError, match="'weights'") as e:
        P.load_prior(tmp_path / "bad.npz")
    assert "bad.npz" in str(e.value)


def test_models_cached_in_float64_serve_a_float32_trace(prior):
    """The training models are cached; a later float32 trace (the command line runs without
    x64) must get float32 parameters, not the float64 ones of the first caller."""
    import equinox as eqx
    from cli_runner import _x64_off

    assert P.training_models(prior) is not None  # made, and cached, with x64 on
    with _x64_off():
        p32 = prior.astype(jnp.float32)
        cfg = aj.Config(budget="iso102")
        par = aj.Params.default(cfg, dtype=jnp.float32)
        meas = aj.sample(aj.materials.get_material("ggx-plastic"), cfg, par, as_measurements=True)
        b = eqx.filter_jit(P.sample_basis)(p32, meas, jnp.float32(np.deg2rad(15.0)))
        assert b.components.dtype == jnp.float32
        assert np.all(np.isfinite(np.asarray(b.components)))
