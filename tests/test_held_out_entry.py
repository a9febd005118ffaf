"""Held-out errors of model selection as numpy matrices (``abrdf_jax.select._held_out_entry``):
the same errors as the JAX path for every default candidate (the min–max rule ``filip2012``
included), kept in the operator store, and the same choices."""

from __future__ import annotations

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import _cache, _engine, materials, select
from abrdf_jax.select import _held_out_entry as H

NAMES = ("ward-brushed-steel", "ggx-aniso-metal", "ashikhmin-satin", "ggx-plastic")


@pytest.fixture(scope="module")
def captures():
    """Grouped aniso204 captures of one layout (1 % noise): ``[(meas, alpha_deg)]``."""
    out = []
    for i, name in enumerate(NAMES):
        m, info = aj.group_slices(
            aj.simulate_capture(materials.get_material(name), noise=0.01, seed=i)
        )
        out.append((m, float(info["alpha_deg"])))
    return out


def _configs():
    return {n: select.CANDIDATES[n].config() for n in select.DEFAULT_ANISO}


def _entry_errors(meas, alpha, configs, k=4):
    out = {}
    for names, cfgs in H.entry_groups(configs):
        entry = H.build_entry(meas, alpha, names, cfgs, k)
        ys = np.asarray(meas.y)[None]
        out.update({n: float(e) for n, e in zip(names, entry.errors(ys)[0])})
    return out


def test_every_default_candidate_has_an_entry():
    rules = {c.subspace_rule for c in _configs().values()}
    assert "filip2012" in rules  # the non-linear rule is covered, not skipped
    assert all(r in H.AFFINE for r in rules)


def test_entry_errors_equal_the_jax_held_out_errors(captures):
    """Float32 rounding apart (the JAX path runs in float32; the entry was built in float64)."""
    configs = _configs()
    for meas, alpha in captures[1:2]:
        want = select.held_out_errors(meas, configs, alpha_deg=alpha)
        got = _entry_errors(meas, alpha, configs)
        assert set(got) == set(want)
        for name in want:
            assert got[name] == pytest.approx(want[name], rel=1e-4), name


def test_a_pair_without_its_axial_slice_reads_the_diagonal_one(captures):
    """An axial slice not measured (count 0): its pair falls back to the diagonal slice in both
    paths (``abrdf_jax._subspace.subspace``), so the errors still agree."""
    meas, alpha = captures[0]
    count = np.asarray(meas.count).copy()
    count[2] = 0  # the axial slice of the second pair
    meas = meas.replace(count=count.astype(np.asarray(meas.count).dtype))
    configs = _configs()
    want = select.held_out_errors(meas, configs, alpha_deg=alpha)
    got = _entry_errors(meas, alpha, configs)
    for name in want:
        assert got[name] == pytest.approx(want[name], rel=1e-4), name


def test_entry_selections_make_the_same_choices_and_use_the_store(captures, tmp_path, monkeypatch):
    store = _cache.OperatorStore(tmp_path / "store")
    warnings, builds, jax_work = [], [], []
    real = H.build_entry

    def counted(*a, **k):
        builds.append(1)
        return real(*a, **k)

    monkeypatch.setattr(H, "build_entry", counted)
    kw = dict(tol=select.TOL, level=select.LEVEL, min_effect=select.MIN_EFFECT)
    first = H.entry_selections(
        captures,
        store=store,
        warn=warnings.append,
        min_group=2,
        before_build=lambda: jax_work.append(1),
        **kw,
    )
    # built in numpy (abrdf_jax._host_build): no JAX work announced
    assert builds and not warnings and not jax_work
    builds.clear()
    again = H.entry_selections(captures, store=store, warn=warnings.append, min_group=2, **kw)
    assert not builds, "the second call read every entry from the store (nothing built)"
    for (meas, alpha), a, b in zip(captures, first, again):
        one = select.select_model(meas, alpha_deg=alpha)
        assert a.name == b.name == one.name
        assert a.errors == pytest.approx(b.errors, rel=0, nan_ok=True)  # read back exactly
        for n, e in one.errors.items():
            assert a.errors[n] == pytest.approx(e, rel=1e-4, nan_ok=True)
    # fewer inputs of the layout than min_group: an entry where the call has few such layouts
    # (the store's, nothing built), direct numpy fits where it has many (no entry, no JAX)
    two = H.entry_selections(captures[:2], store=store, warn=warnings.append, min_group=3, **kw)
    assert not builds and [s.name for s in two] == [s.name for s in first[:2]]
    assert two[0].errors == pytest.approx(first[0].errors, rel=1e-6)  # two rows, not four
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 0)
    direct = H.entry_selections(captures[:2], store=store, warn=warnings.append, min_group=3, **kw)
    assert not builds and [s.name for s in direct] == [s.name for s in first[:2]]
    assert direct[0].errors == pytest.approx(first[0].errors, rel=1e-4)  # float64 vs the entry's
    # ... and a lone layout (no other input has its slice positions: a jittered capture's) takes
    # the direct fits even where the call has few small layouts: an entry would serve it alone
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 16)
    (alone,) = H.entry_selections(captures[:1], store=None, warn=warnings.append, min_group=2, **kw)
    assert not builds and alone.name == first[0].name
    assert alone.errors == pytest.approx(direct[0].errors, rel=1e-9)  # the same float64 fits


def test_a_corrupt_stored_entry_is_rebuilt(captures, tmp_path):
    meas, alpha = captures[1]
    store = _cache.OperatorStore(tmp_path / "store")
    (names, cfgs), *_ = H.entry_groups(_configs())
    built = H.cached_entry(store, meas, alpha, names, cfgs, 4, print)
    files = [p for p in (tmp_path / "store").rglob("*") if p.is_file() and p.suffix == ".npz"]
    assert len(files) == 1
    files[0].write_bytes(files[0].read_bytes()[:200])  # truncated
    warnings = []
    again = H.cached_entry(store, meas, alpha, names, cfgs, 4, warnings.append)
    assert warnings and "rebuil" in " ".join(warnings).lower()
    np.testing.assert_array_equal(again.terms, built.terms)
    np.testing.assert_array_equal(
        again.errors(np.asarray(meas.y)[None]), built.errors(np.asarray(meas.y)[None])
    )
