"""The prior-only model on the operator path and in the automatic choice (issue 14).

``reconstruct --model prior`` reproduces :func:`abrdf_jax.prior.reconstruct_prior` (float64) to
float32 rounding, single file and folder; the operator store keeps its entries like the RBF's;
a bad prior file is an input error naming it; ``--model auto --prior`` keeps the RBF on an
anisotropic material and may choose the prior on a material of the prior's own family. A small
prior trained on the package's analytic draws stands in for a database (no ../shared).
"""

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import io, materials
from abrdf_jax import prior as P
from abrdf_jax import select
from abrdf_jax._cache import OperatorEntry, OperatorStore
from abrdf_jax._prior_entry import PriorEntry
from abrdf_jax._prior_operator import PriorModel, build_prior_entry, read_source
from abrdf_jax.prior._default import DEFAULT_RECIPE

from cli_runner import call_cli

ALPHA = np.deg2rad(aj.PROTOCOL_ALPHA_DEG)


@pytest.fixture(scope="module")
def small_prior():
    """40 analytic draws of the default recipe, K = 12: a prior of isotropic materials."""
    tables, names = P.default_training_tables({**DEFAULT_RECIPE, "n": 40})
    return P.train_prior(tables, names, k=12, lam=0.03)


@pytest.fixture(scope="module")
def prior_file(small_prior, tmp_path_factory):
    return P.save_prior(small_prior, tmp_path_factory.mktemp("prior") / "small.npz")


def _meas(name, budget, dtype=jnp.float32):
    model = materials.get_material(name)
    return aj.sample(model, aj.Config(budget=budget), as_measurements=True).astype(dtype)


def _oracle(prior, meas):
    """``reconstruct_prior`` in float64."""
    return np.asarray(P.reconstruct_prior(meas.astype(jnp.float64), prior.astype(jnp.float64)))


@pytest.mark.parametrize("channels", ["shared", "joint"])
@pytest.mark.parametrize("budget", ["iso102", "aniso204"])
def test_entry_reproduces_reconstruct_prior(small_prior, budget, channels):
    prior = small_prior
    if channels == "joint":
        tables, names = P.default_training_tables({**DEFAULT_RECIPE, "n": 12})
        prior = P.train_prior(tables, names, k=6, lam=0.03, channels="joint")
    meas = _meas("ashikhmin-satin", budget)
    entry = build_prior_entry(prior, meas, ALPHA, float(prior.lam), np.asarray(meas.count))
    out = entry.apply(np.asarray(meas.y)[None])[0]
    want = _oracle(prior, meas)
    assert out.dtype == np.float32 and out.shape == (81, 81, 3)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-5 * want.max())


def test_iso102_entry_reads_the_diagonal_slices_only(small_prior):
    meas = _meas("ggx-plastic", "aniso204")
    count = np.asarray(meas.count).copy()
    count[0::2] = 0
    entry = build_prior_entry(small_prior, meas, ALPHA, float(small_prior.lam), count)
    y = np.asarray(meas.y).copy()
    y[0::2] = 1e3  # the axial slices are not read
    out = entry.apply(y[None])[0]
    want = _oracle(small_prior, meas.replace(count=jnp.asarray(count, meas.count.dtype)))
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-5 * want.max())


def test_store_keeps_prior_entries_apart(small_prior, tmp_path):
    meas = _meas("ggx-plastic", "iso102")
    entry = build_prior_entry(small_prior, meas, ALPHA, 0.03, np.asarray(meas.count))
    warned = []
    store = OperatorStore(tmp_path, warn=warned.append)
    assert store.save("k", entry)
    back = store.load("k", kind=PriorEntry)
    assert all(np.array_equal(a, back.arrays()[n]) for n, a in entry.arrays().items())
    assert store.load("k", kind=OperatorEntry) is None  # another kind: rejected and removed
    assert "of another kind" in warned[0] and not store.path("k").exists()


def test_auto_keeps_the_rbf_on_anisotropic_and_may_choose_the_prior(small_prior):
    aniso = _meas("ggx-aniso-metal", "aniso204")
    plastic = _meas("ggx-plastic", "aniso204")
    sa = select.select_model(aniso, prior=small_prior)
    sp = select.select_model(plastic, prior=small_prior)
    assert sa.name in select.CANDIDATES and sa.config.budget == "aniso204", sa.reason
    assert "prior" in sa.errors and sa.errors["prior"] > sa.errors[sa.name]
    # the fused model is scored too, but left out: the prior alone is worse than the kernel
    assert "fused" in sa.errors and "fused left out" in sa.reason, sa.reason
    assert sp.name in ("prior", "fused"), sp.reason  # a material of the prior's own family
    assert sp.config.budget == "iso102"  # isotropic: the prior on the diagonal slices
    assert select.select_model(plastic, prior=small_prior, fused=False).name == "prior"
    # a folder's batched choice: the same choices and errors
    both = select.select_models([aniso, plastic], prior=small_prior)
    assert [s.name for s in both] == [sa.name, sp.name]
    for s, one in zip(both, (sa, sp)):
        for n, e in one.errors.items():
            np.testing.assert_allclose(s.errors[n], e, rtol=1e-4)


def _csv(tmp_path, name, material, budget):
    samples = aj.sample(materials.get_material(material), aj.Config(budget=budget))
    io.write_samples_csv(tmp_path / name, samples)
    return samples


def test_cli_model_prior_file_and_folder(small_prior, prior_file, tmp_path):
    (tmp_path / "d").mkdir()
    cases = {"iso.csv": ("ggx-plastic", "iso102"), "an.csv": ("rough-fabric", "aniso204")}
    samples = {n: _csv(tmp_path / "d", n, *mb) for n, mb in cases.items()}
    cache = ["--cache-dir", tmp_path / "cache"]
    one = call_cli("reconstruct", "d/an.csv", "-o", "an.npz", "--model", "prior", "--prior",
                  prior_file, *cache, cwd=tmp_path)  # fmt: skip
    assert one.returncode == 0, one.stderr
    many = call_cli("reconstruct", "d", "-o", "out", "--model", "prior", "--prior", prior_file,
                   "-q", *cache, cwd=tmp_path)  # fmt: skip
    assert many.returncode == 0, many.stderr
    assert "2 by the operator" in many.stdout
    record = json.loads((tmp_path / "an.model.json").read_text())
    assert record["model"] == "prior" and record["engine"] == "operator"
    src = read_source(prior_file)
    assert record["prior"]["sha256"] == src.sha256 and record["prior"]["file"] == str(prior_file)
    assert record["prior"]["n_components"] == 12 and record["prior"]["provenance"]
    for name, table in (("an.csv", tmp_path / "an.npz"), ("iso.csv", tmp_path / "out/iso.npz"),
                        ("an.csv", tmp_path / "out/an.npz")):  # fmt: skip
        meas, _ = aj.group_slices(samples[name], aj.PROTOCOL_ALPHA_DEG, dtype=np.float64)
        want = _oracle(small_prior, meas)
        got = io.read_table(table)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * want.max())
    folder = json.loads((tmp_path / "out.model.json").read_text())["inputs"]
    assert {e["config"]["budget"] for e in folder} == {"iso102", "aniso204"}


def test_cli_bad_prior_file_is_an_input_error(prior_file, tmp_path):
    _csv(tmp_path, "m.csv", "ggx-plastic", "iso102")
    raw = prior_file.read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    for bad in ("cut.npz", "missing.npz"):
        r = call_cli("reconstruct", "m.csv", "-o", "m.npz", "--model", "prior", "--prior", bad,
                    cwd=tmp_path)  # fmt: skip
        assert r.returncode == 2 and bad in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert not (tmp_path / "m.npz").exists()
    r = call_cli("reconstruct", "m.csv", "-o", "m.npz", "--model", "iso", "--prior", prior_file,
                cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2 and "--prior" in r.stderr


def test_cli_auto_with_prior(prior_file, tmp_path):
    (tmp_path / "d").mkdir()
    _csv(tmp_path / "d", "aniso.csv", "ggx-aniso-metal", "aniso204")
    _csv(tmp_path / "d", "plastic.csv", "ggx-plastic", "aniso204")
    r = call_cli("reconstruct", "d", "-o", "out", "--prior", prior_file, "-q",
                "--cache-dir", tmp_path / "cache", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    entries = json.loads((tmp_path / "out.model.json").read_text())["inputs"]
    rec = {Path(e["input"]).name: e for e in entries}
    aniso, plastic = rec["aniso.csv"], rec["plastic.csv"]
    assert aniso["model"] in select.CANDIDATES and aniso["config"]["budget"] == "aniso204"
    assert "prior" in [c["name"] for c in aniso["candidates"]]
    assert plastic["model"] in ("prior", "fused") and plastic["how"] == "auto"
    assert {"prior", "fused"} <= {c["name"] for c in plastic["candidates"]}
    assert plastic["prior"]["sha256"] == read_source(prior_file).sha256


def test_prior_model_is_hashable_and_names_its_budget(prior_file):
    src = read_source(prior_file)
    a, b = PriorModel(src, "iso102"), PriorModel(read_source(prior_file), "iso102")
    assert a == b and hash(a) == hash(b) and a != PriorModel(src, "aniso204")


@pytest.mark.parametrize("name", ["prior", "fused"])
def test_learned_held_out_entry_equals_the_jax_held_out_errors(small_prior, prior_file, name):
    """The numpy held-out entry of a learned model (what a warm ``--model auto --prior`` reads)
    gives the JAX path's held-out errors (float64 oracle) to float32 rounding, on both budgets,
    for a material of the prior's family and one unlike it; a tampered entry is rejected by the
    store (named, rebuilt), never used."""
    from abrdf_jax.select._fused import fused_held_out_error
    from abrdf_jax.select._learned_entry import (
        LearnedHeldOutEntry,
        build_entry,
        cached_entry,
        learned_model,
    )
    from abrdf_jax.select._prior import prior_held_out_error

    src = read_source(prior_file)
    metas = [_meas(n, "aniso204") for n in ("ggx-plastic", "ggx-aniso-metal")]
    y = np.stack([np.asarray(m.y) for m in metas])
    held_out = prior_held_out_error if name == "prior" else fused_held_out_error
    p64 = small_prior.astype(jnp.float64)
    for budget in ("iso102", "aniso204"):
        entry = build_entry(learned_model(name, src, budget), metas[0], 15.0, 4)
        want = [held_out(m.astype(jnp.float64), p64, ALPHA, 4, budget) for m in metas]
        np.testing.assert_allclose(entry.errors(y), want, rtol=2e-4)
    assert want[1] > 2 * want[0]  # the anisotropic material is held out far worse
    store, warned = OperatorStore(Path(prior_file).parent / f"store-{name}"), []
    model = learned_model(name, src, "aniso204")
    first = cached_entry(store, model, metas[0], 15.0, 4, warned.append)
    (path,) = store.entries()
    again = cached_entry(
        store, model, metas[0], 15.0, 4, warned.append, lambda: pytest.fail("built again")
    )
    np.testing.assert_array_equal(again.errors(y), first.errors(y))
    bad = LearnedHeldOutEntry(**{**first.arrays(), "gain": first.gain[:, :-1]}, **first.meta())
    store.save(path.stem, bad)
    rebuilt = cached_entry(store, model, metas[0], 15.0, 4, warned.append)
    assert warned and "malformed" in warned[0] and str(path) in warned[0]
    np.testing.assert_array_equal(rebuilt.errors(y), first.errors(y))
