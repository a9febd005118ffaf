"""Held-out errors of model selection on dense captures in numpy
(``abrdf_jax.select._dense_held_out``): the JAX path's fits (``select._select._cv_core``) in
float64, one RBF solve for several captures, and the automatic choice without JAX."""

from __future__ import annotations

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import _cache, io, materials, select
from abrdf_jax._grouping import group_arrays
from abrdf_jax.select import _held_out_entry as H
from abrdf_jax.select._dense_held_out import dense_errors

# per_slice 60: at least DENSE_KNOTS (48) samples a diagonal slice, the denser centre layout
DENSE = dict(per_slice=60, jitter_deg=0.3, noise=0.01)


def _grouped(name: str, seed: int, tmp_path, **kw):
    """A dense capture grouped as the command line groups it (numpy), and its α."""
    s = aj.simulate_capture(materials.get_material(name), seed=seed, **{**DENSE, **kw})
    path = tmp_path / f"{name}-{seed}.csv"
    io.write_samples_csv(path, s)
    meas, report = group_arrays(io.read_sample_columns(path), None)
    assert meas.centre_azimuths is not None  # dense
    return meas, float(report["alpha_deg"])


def _float64(meas):
    """The JAX measurement of numpy slices in float64 (inside an ``x64_scope``)."""
    import jax.numpy as jnp

    m = meas.to_measurements() if hasattr(meas, "to_measurements") else meas
    return m.replace(t=jnp.asarray(m.t, jnp.float64), y=jnp.asarray(m.y, jnp.float64))


def _numpy(meas_list, configs, k=4):
    out = [{} for _ in meas_list]
    for names, cfgs in H.entry_groups(configs):
        found = dense_errors(
            [m for m, _ in meas_list], [np.asarray(m.y) for m, _ in meas_list],
            [a for _, a in meas_list], cfgs, k,
        )  # fmt: skip
        for row, err in zip(out, found):
            row.update({n: float(e) for n, e in zip(names, err)})
    return out


@pytest.mark.parametrize(
    "names",
    [select.DEFAULT_ANISO, ("iso-linear", "paper-aniso")],
    ids=["default-aniso", "linear-values"],
)
def test_dense_errors_equal_the_float64_jax_path(tmp_path, names):
    """Every default anisotropic candidate (one kernel group: the rules ``diagonal``,
    ``average``, ``crossing`` and the min–max ``filip2012``), and linear value spaces (a
    Gaussian kernel among them): the JAX path's held-out errors run in float64, to 1e-8."""
    meas, alpha = _grouped("ggx-aniso-metal", 3, tmp_path)
    configs = {n: select.CANDIDATES[n].config() for n in names}
    (got,) = _numpy([(meas, alpha)], configs)
    with _cache.x64_scope(True):
        want = select.held_out_errors(_float64(meas), configs, alpha_deg=alpha)
    assert set(got) == set(want)
    for name in want:
        assert np.isfinite(got[name])
        assert got[name] == pytest.approx(want[name], rel=1e-8), name


def test_captures_of_one_pair_layout_share_one_solve(tmp_path):
    """Captures of other layouts, α and materials in one call (the columns of one RBF solve):
    each one's errors as computed alone."""
    a = _grouped("ggx-aniso-metal", 1, tmp_path)
    b = _grouped("ward-brushed-steel", 2, tmp_path, per_slice=80, alpha_deg=20.0)
    assert np.shape(a[0].t) != np.shape(b[0].t) and a[1] != pytest.approx(b[1], abs=1.0)
    configs = {n: select.CANDIDATES[n].config() for n in select.DEFAULT_ANISO}
    both = _numpy([a, b], configs)
    for one, alone in zip(both, (_numpy([a], configs)[0], _numpy([b], configs)[0])):
        for name in configs:
            assert one[name] == pytest.approx(alone[name], rel=1e-9), name


def test_entry_selections_choose_a_dense_capture_in_numpy(tmp_path):
    """``--model auto``'s JAX-free choice takes dense captures (``dense_plan``): the held-out
    errors of the JAX path run in float64, and the tolerance rule's pick on them."""
    meas, alpha = _grouped("ggx-aniso-metal", 3, tmp_path)
    (sel,) = H.entry_selections(
        [(meas, alpha)], store=None, warn=print, tol=select.TOL, level=select.LEVEL,
        min_effect=select.MIN_EFFECT, min_group=1,
    )  # fmt: skip
    assert sel is not None  # chosen here, not left to the JAX path
    configs = {n: select.CANDIDATES[n].config() for n in sel.errors}
    assert set(configs) == set(select.DEFAULT_ANISO)
    with _cache.x64_scope(True):
        want = select.held_out_errors(_float64(meas), configs, alpha_deg=alpha)
    for name, e in want.items():
        assert sel.errors[name] == pytest.approx(e, rel=1e-8), name
    assert sel.name == select.tolerance_choice(want, sel.ranks, select.TOL)[0]


def test_select_model_and_select_models_score_dense_captures_in_numpy(tmp_path):
    """The library's choice of a dense capture is the command line's: ``select_model`` and
    ``select_models`` (a folder's, with a sparse capture beside the dense ones) give the same
    errors as ``entry_selections``, in float64 whatever the measurement's dtype."""
    dense = [_grouped("ggx-aniso-metal", 3, tmp_path), _grouped("ward-brushed-steel", 4, tmp_path)]
    s = aj.simulate_capture(materials.get_material("ggx-aniso-metal"), noise=0.01, seed=5)
    sparse = aj.group_slices(s)
    sparse = (sparse[0], float(sparse[1]["alpha_deg"]))
    kw = dict(tol=select.TOL, level=select.LEVEL, min_effect=select.MIN_EFFECT)
    cli = H.entry_selections(dense, store=None, warn=print, min_group=1, **kw)
    one = [select.select_model(m.to_measurements(), alpha_deg=a) for m, a in dense]
    many = select.select_models(
        [m.to_measurements() for m, _ in dense] + [sparse[0]],
        alpha_deg=[a for _, a in dense] + [sparse[1]],
    )
    for c, o, b in zip(cli, one, many):
        assert c.name == o.name == b.name
        for name, e in c.errors.items():
            assert o.errors[name] == pytest.approx(e, rel=1e-12), name
            assert b.errors[name] == pytest.approx(e, rel=1e-12), name
    # the sparse capture still takes the JAX path (float32): its own choice, as alone
    alone = select.select_model(sparse[0], alpha_deg=sparse[1])
    assert many[2].name == alone.name
    assert many[2].errors == pytest.approx(alone.errors, rel=1e-4)


def test_a_folder_of_jittered_captures_is_chosen_by_direct_fits():
    """More jittered sparse captures (a layout each) than the small-layout rule gives entries
    (``OPERATOR_MAX_BUILDS``): the command line's choice scores them by the same direct fits
    (``direct_plan``: one solve on the UBO centres), not in JAX; the errors are the JAX path's
    in float64."""
    from abrdf_jax import _engine

    n = _engine.OPERATOR_MAX_BUILDS + 1
    items = []
    for k in range(n):
        s = aj.simulate_capture(
            materials.get_material("ggx-aniso-metal"), jitter_deg=0.5, noise=0.01, seed=40 + k
        )
        meas, info = aj.group_slices(s)
        items.append((meas, float(info["alpha_deg"])))
    sels = H.entry_selections(
        items, store=None, warn=print, tol=select.TOL, level=select.LEVEL,
        min_effect=select.MIN_EFFECT,
    )  # fmt: skip
    assert all(s is not None for s in sels)  # none left to the JAX path
    meas, alpha = items[0]
    configs = {n: select.CANDIDATES[n].config() for n in sels[0].errors}
    assert len(configs) > 1 and meas.centre_azimuths is None  # a sparse layout, compared
    with _cache.x64_scope(True):
        want = select.held_out_errors(_float64(meas), configs, alpha_deg=alpha)
    for name, e in want.items():
        assert sels[0].errors[name] == pytest.approx(e, rel=1e-8), name


def test_the_stored_coefficient_map_gives_the_same_errors(tmp_path):
    """With an operator store the system's coefficient map ``A⁻¹ [I; 0]`` is built once (kind
    ``centre-map``, keyed by the pairs, centres and kernel setting: not by the layout nor α)
    and read by a capture of another layout; the errors equal one solve's."""
    a = _grouped("ggx-aniso-metal", 1, tmp_path)
    b = _grouped("ward-brushed-steel", 2, tmp_path, per_slice=80, alpha_deg=20.0)
    configs = {n: select.CANDIDATES[n].config() for n in select.DEFAULT_ANISO}
    ((names, cfgs),) = H.entry_groups(configs)
    store = _cache.OperatorStore(tmp_path / "store")
    warnings = []
    for m, alpha in (a, b, a):
        args = ([m], [np.asarray(m.y)], [alpha], cfgs, 4)
        got = dense_errors(*args, store=store, warn=warnings.append)
        np.testing.assert_allclose(got, dense_errors(*args), rtol=1e-9)
    assert len(store.entries()) == 1 and not warnings
