"""The fused model on the operator path, on the command line and in the automatic choice
(issue 14, "Operator and batch", "Model choice").

The numpy entry equals the library's fused posterior mean (:func:`abrdf_jax.prior.reconstruct_fused`
in float64) to float32 rounding; the operator store keeps fused entries apart from the others;
``reconstruct --model fused`` runs a file and a folder; a bad ``fused`` member of a prior file
is an input error naming the file and the field. A small prior of analytic draws stands in for
a database (no ../shared).
"""

import dataclasses
import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials
from abrdf_jax import prior as P
from abrdf_jax._cache import OperatorStore
from abrdf_jax._fused_entry import FusedEntry
from abrdf_jax._fused_operator import FusedModel, build_fused_entry
from abrdf_jax._prior_entry import PriorEntry
from abrdf_jax._prior_operator import PriorModel, prior_entry_key, read_source, slice_counts
from abrdf_jax.prior._default import DEFAULT_RECIPE
from abrdf_jax.prior._fused_settings import FUSED_DEFAULTS

from cli_runner import call_cli

ALPHA = np.deg2rad(aj.PROTOCOL_ALPHA_DEG)


@pytest.fixture(scope="module")
def small_prior():
    """12 analytic draws of the default recipe, K = 6: a prior of isotropic materials."""
    tables, names = P.default_training_tables({**DEFAULT_RECIPE, "n": 12})
    return P.train_prior(tables, names, k=6, lam=0.03)


@pytest.fixture(scope="module")
def prior_file(small_prior, tmp_path_factory):
    return P.save_prior(small_prior, tmp_path_factory.mktemp("prior") / "small.npz")


def _meas(name, budget):
    model = materials.get_material(name)
    return aj.sample(model, aj.Config(budget=budget), as_measurements=True)


@eqx.filter_jit
def _fused64(meas, prior, hyper):
    return P.reconstruct_fused(meas, prior, hyper, reference="log")


def _oracle(prior, meas, settings=FUSED_DEFAULTS):
    """``reconstruct_fused`` in float64 (the library's posterior mean)."""
    f64 = jnp.float64
    return np.asarray(
        _fused64(meas.astype(f64), prior.astype(f64), P.FusedHyper.from_settings(settings, f64))
    )


@pytest.fixture(scope="module")
def iso_entry(small_prior):
    """The iso102 entry of an aniso204 layout (the axial slices are not read) and the oracle."""
    meas = _meas("ggx-plastic", "aniso204")
    counts = slice_counts(meas, "iso102")
    entry = build_fused_entry(small_prior, meas, ALPHA, FUSED_DEFAULTS, counts)
    want = _oracle(small_prior, meas.replace(count=jnp.asarray(counts, meas.count.dtype)))
    return meas, entry, want


def test_entry_equals_the_fused_posterior_mean(iso_entry):
    meas, entry, want = iso_entry
    y = np.asarray(meas.y).copy()
    y[0::2] = 1e3  # the axial slices are not read
    out = entry.apply(y[None])[0]
    assert out.dtype == np.float32 and out.shape == (81, 81, 3)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-5 * want.max())
    # a batch is the same as one by one
    y2 = np.stack([y, 0.5 * y])
    np.testing.assert_allclose(entry.apply(y2)[1], entry.apply(y2[1:])[0], rtol=1e-6)


def test_entries_clip_at_the_ceiling_as_the_library_does(small_prior):
    """The numpy entries (fused and prior only) clip at the prior's ceiling exactly as the JAX
    reconstructions do (oracle: float64 library), here with a ceiling lowered so that most of
    the table is clipped; the BTF chunk map collapses the same entry (tests/test_btf.py)."""
    from abrdf_jax._prior_operator import build_prior_entry

    low = eqx.tree_at(lambda p: p.ceiling, small_prior, small_prior.mean - 3.0)
    meas = _meas("ggx-plastic", "aniso204")
    counts = np.asarray(meas.count)
    fused = build_fused_entry(low, meas, ALPHA, FUSED_DEFAULTS, counts).apply(meas.y[None])[0]
    want = _oracle(low, meas)
    np.testing.assert_allclose(fused, want, rtol=0, atol=1e-5 * want.max())
    assert want.max() < 0.5 * _oracle(small_prior, meas).max()  # the lowered ceiling bites
    alone = build_prior_entry(low, meas, ALPHA, float(low.lam), counts).apply(meas.y[None])[0]
    want = np.asarray(P.reconstruct_prior(meas.astype(jnp.float64), low.astype(jnp.float64)))
    np.testing.assert_allclose(alone, want, rtol=0, atol=1e-5 * want.max())


def test_store_round_trip_and_key(iso_entry, prior_file, tmp_path):
    meas, entry, _ = iso_entry
    warned = []
    store = OperatorStore(tmp_path, warn=warned.append)
    assert store.save("k", entry)
    back = store.load("k", kind=FusedEntry)
    assert all(np.array_equal(a, back.arrays()[n]) for n, a in entry.arrays().items())
    y = np.asarray(meas.y)[None]
    np.testing.assert_array_equal(back.apply(y), entry.apply(y))
    assert store.load("k", kind=PriorEntry) is None  # another kind: rejected and removed
    assert "of another kind" in warned[0] and not store.path("k").exists()
    # the key: its own kind, and every hyper-parameter
    src = read_source(prior_file)
    params = aj.Params.default(aj.Config(budget="iso102"))
    fused = FusedModel(src, "iso102")
    keys = {prior_entry_key(m, meas, params) for m in (fused, PriorModel(src, "iso102"))}
    other = {**src.fused_settings(), "sigma_k": 0.2}
    changed = FusedModel(dataclasses.replace(src, fused=json.dumps(other)), "iso102")
    keys.add(prior_entry_key(changed, meas, params))
    assert len(keys) == 3


def _csv(path, material, budget):
    samples = aj.sample(materials.get_material(material), aj.Config(budget=budget))
    io.write_samples_csv(path, samples)
    return samples


def test_cli_model_fused_folder_and_file(small_prior, prior_file, tmp_path):
    """A folder of two aniso204 files (one layout: one entry built), then one of them alone
    (the stored entry, no build); the tables are the library's fused posterior mean."""
    (tmp_path / "d").mkdir()
    samples = {n: _csv(tmp_path / "d" / n, m, "aniso204")
               for n, m in (("pl.csv", "ggx-plastic"), ("an.csv", "ggx-aniso-metal"))}  # fmt: skip
    cache = ["--cache-dir", tmp_path / "cache"]
    many = call_cli("reconstruct", "d", "-o", "out", "--model", "fused", "--prior", prior_file,
                   "-q", *cache, cwd=tmp_path)  # fmt: skip
    assert many.returncode == 0, many.stderr
    assert "2 by the operator" in many.stdout
    one = call_cli("reconstruct", "d/pl.csv", "-o", "pl.npz", "--model", "fused", "--prior",
                  prior_file, *cache, cwd=tmp_path)  # fmt: skip
    assert one.returncode == 0, one.stderr
    record = json.loads((tmp_path / "pl.model.json").read_text())
    assert record["model"] == "fused" and record["engine"] == "operator"
    assert record["params"]["fused"]["sigma_k"] == FUSED_DEFAULTS["sigma_k"]
    assert record["params"]["fused"]["origin"].startswith("package defaults")
    assert record["prior"]["sha256"] == read_source(prior_file).sha256
    meas, _ = aj.group_slices(samples["pl.csv"], aj.PROTOCOL_ALPHA_DEG, dtype=np.float64)
    want = _oracle(small_prior, meas)
    for table in ("pl.npz", "out/pl.npz"):
        np.testing.assert_allclose(io.read_table(tmp_path / table), want, atol=1e-5 * want.max())


def test_cli_bad_fused_member_is_an_input_error(small_prior, tmp_path):
    _csv(tmp_path / "m.csv", "ggx-plastic", "iso102")
    bad = dataclasses.replace(
        small_prior, meta=json.dumps({"fused": {**FUSED_DEFAULTS, "sigma_n": -1}})
    )
    P.save_prior(bad, tmp_path / "bad.npz")
    r = call_cli("reconstruct", "m.csv", "-o", "m.npz", "--model", "fused", "--prior", "bad.npz",
                cwd=tmp_path)  # fmt: skip
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "bad.npz" in lines[0] and "'fused'" in lines[0] and "sigma_n" in lines[0]
    assert not (tmp_path / "m.npz").exists()
