"""The batch engine of the command line (abrdf_jax._engine) and the folder run built on it:
operator groups, fixed batch shapes (no recompile for the last batch), the record after every
batch, --resume and an interrupted run."""

import json
from collections import Counter

import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax import _engine, _pipeline, io, materials
from abrdf_jax.cli import _common, main, reconstruct

NAMES = ("ggx-plastic", "lambert-clay", "ward-brushed-steel", "rough-fabric", "ashikhmin-satin")


def _meas(name, budget="iso102", **kw):
    s = aj.simulate_capture(materials.get_material(name), budget=budget, **kw)
    return aj.group_slices(s)[0]


def test_operator_groups_match_the_pipeline_and_ignore_the_batch_size(monkeypatch):
    config = aj.preset("recommended", "iso102")
    params = aj.Params.default(config)
    meas = [_meas(n) for n in NAMES]
    assert all(_engine.operator_applies(config, m) for m in meas)
    assert len({_engine.layout_key(m) for m in meas}) == 1  # one template, one operator
    built, shared = [], []

    def operator(c, p, template, **kw):
        built.append(template)
        shared.append(kw.get("shared", False))
        return aj.compile_operator(c, p, template, nonlinear="two_stage" if shared[-1] else "raise")

    whole = list(
        _engine.reconstruct_many(meas, config, params, operator=operator, batch=8, min_group=1)
    )
    assert len(built) == 1 and [len(i) for i, _, _ in whole] == [5]
    ((idx, tables, path),) = whole
    assert idx == list(range(5)) and path == "operator" and tables.shape == (5, 81, 81, 3)
    expected = np.asarray(aj.reconstruct_batch(meas, config, params))
    np.testing.assert_allclose(tables, expected, rtol=0, atol=2e-3 * expected.max())
    # batches of 2 (the last one padded): the same tables, bit for bit
    parts = list(_engine.reconstruct_many(meas, config, params, batch=2, min_group=1))
    assert [i for i, _, _ in parts] == [[0, 1], [2, 3], [4]]
    np.testing.assert_array_equal(np.concatenate([t for _, t, _ in parts]), tables)
    # fewer than OPERATOR_MIN_GROUP of a layout: still an operator in a job of few layouts
    few = list(_engine.reconstruct_many(meas, config, params, operator=operator))
    assert len(built) == 2 and {p for *_, p in few} == {"operator"}
    few_tables = np.concatenate([t for _, t, _ in few])  # a batch of 256: BLAS's rounding
    np.testing.assert_allclose(few_tables, tables, rtol=1e-5, atol=1e-6 * expected.max())
    # ... and in a job of many (every jittered capture a layout of its own) the two-stage form,
    # whose second stage every layout shares (an affine rule on the log of the samples)
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 0)
    many = list(_engine.reconstruct_many(meas, config, params, operator=operator))
    assert len(built) == 3 and shared == [False, False, True]
    assert {p for *_, p in many} == {"operator"}
    np.testing.assert_allclose(many[0][1], tables, rtol=0, atol=2e-3 * expected.max())
    # ... the pipeline on linear values (no two-stage form there)
    linear = aj.preset("recommended", "iso102", value_space="linear")
    lparams = aj.Params.default(linear)
    assert all(_engine.operator_applies(linear, m) for m in meas)
    plain = list(_engine.reconstruct_many(meas, linear, lparams, operator=operator))
    assert len(built) == 3 and {p for *_, p in plain} == {"pipeline"}


def test_many_jittered_layouts_share_one_second_stage_without_a_store(monkeypatch):
    """The library's default operators (no store): a job of more small layouts than
    ``OPERATOR_MAX_BUILDS`` (jittered captures, a layout each) on the log of the samples reads
    one second stage, built once in numpy and kept in memory, and matches the pipeline."""
    from abrdf_jax import _cache

    config = aj.preset("recommended", "aniso204", rule="crossing")
    params = aj.Params.default(config)
    meas = [_meas(n, "aniso204", jitter_deg=0.5, seed=k) for k, n in enumerate(NAMES[:3])]
    assert len({_engine.layout_key(m) for m in meas}) == 3
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 2)
    monkeypatch.setattr(_cache, "_SHARED", {})
    builds = []
    real = _cache.build_entry
    monkeypatch.setattr(_cache, "build_entry", lambda *a, **k: builds.append(k) or real(*a, **k))
    parts = list(_engine.reconstruct_many(meas, config, params))
    assert {p for *_, p in parts} == {"operator"} and len(parts) == 3
    assert len(builds) == 1 and builds[0]["two_stage"]  # one second stage for the three
    for idx, tables, _ in parts:
        want = np.asarray(aj.reconstruct(meas[idx[0]], config, params))
        np.testing.assert_allclose(tables[0], want, rtol=0, atol=5e-4 * want.max())


def test_lone_layouts_take_the_shared_second_stage_within_the_small_layout_rule():
    """A layout no other input of the block shares (``lone_layouts``: a jittered capture's,
    counted with the inputs an interrupted run kept) reads its setting's shared second stage
    even where the small-layout rule would build it an operator of its own, and costs no build;
    a layout two inputs share keeps its operator; a setting without the shared form (linear
    values) and a learned or bivariate map keep theirs."""
    config = aj.preset("recommended", "aniso204", rule="crossing")
    done = [_engine.Done("kept", "g", 0, 32), _engine.Done(None, "p", 1, 32)]
    lone = _engine.lone_layouts(["a", "b", "b", None, "kept", "c"], done)
    assert lone == {"a", "c"}  # "kept": once here, once kept: not lone
    sizes = Counter({"a": 1, "b": 2})
    layouts = _engine.Layouts(["a", "b", "b"], sizes, {k: ("layout", k) for k in sizes})
    meas = [_meas(n, "aniso204") for n in NAMES[:3]]
    plan = _engine.plan_job(meas, config, layouts=layouts, small=True, lone=lone)
    kinds = {tuple(g["members"]): g["shared"] for g in plan.values()}
    assert kinds == {(0,): True, (1, 2): False}
    assert _engine.build_cost(_engine.small_build_set(layouts, config, lone=lone)) == 1
    assert _engine.build_cost(_engine.small_build_set(layouts, config)) == 2
    linear = aj.preset("recommended", "aniso204", rule="crossing", value_space="linear")
    plan = _engine.plan_job(meas, linear, layouts=layouts, small=True, lone=lone)
    assert not any(g["shared"] for g in plan.values()) and len(plan) == 2
    from abrdf_jax._bivariate import BivariateModel

    plan = _engine.plan_job(
        meas, BivariateModel("aniso204"), layouts=layouts, small=True, lone=lone
    )
    assert not any(g["shared"] for g in plan.values())
    # a two-stage layout (its map is the setting's already) keeps its group
    two = ("two-stage", ((30.0, 30.0),), None)
    staged = _engine.Layouts(["a", "b", "b"], sizes, {"a": two, "b": two})
    plan = _engine.plan_job(meas, config, layouts=staged, small=True, lone=lone)
    assert not any(g["shared"] for g in plan.values())


def test_host_operators_are_not_padded_beyond_the_jobs_group():
    """``host=True`` (the command line's numpy entries, which compile nothing): a group's
    batches have at most the whole job's group rows (one file: one row, not a batch of 256
    copies; a resumed run the same shape); else every batch has ``batch`` rows."""
    from abrdf_jax import _cache
    from abrdf_jax._config import default_values

    config = aj.preset("recommended", "iso102")
    params = default_values(config, 15.0)
    meas = [_meas(n, noise=0.01, seed=k) for k, n in enumerate(NAMES[:3])]  # one layout
    entry, _ = _cache.cached_entry(None, meas[0], config, params)
    rows = []

    def operator(c, p, template):
        def apply(y):
            rows.append(len(y))
            return entry.apply(y)

        return apply

    run = dict(operator=operator, min_group=1)
    one = list(_engine.reconstruct_many(meas[:1], config, params, host=True, **run))
    assert rows == [1] and one[0][1].shape == (1, 81, 81, 3)
    rows.clear()
    three = list(_engine.reconstruct_many(meas, config, params, host=True, batch=2, **run))
    assert rows == [2, 2] and [i for i, _, _ in three] == [[0, 1], [2]]
    rows.clear()
    list(_engine.reconstruct_many(meas[:1], config, params, **run))
    assert rows == [_engine.OPERATOR_BATCH]
    np.testing.assert_allclose(one[0][1][0], three[0][1][0], rtol=1e-5)


def test_small_builds_count_the_layouts_below_min_group():
    """What a job's small layouts would cost in builds: layouts below ``min_group`` (done ones
    included), one each; a two-stage map (shared by every layout of its pairs and centres)
    ``TWO_STAGE_BUILD_COST`` once; ``None`` (no operator applies) and big layouts nothing."""
    config = aj.preset("recommended", "iso102")
    sizes = Counter({"big": 40, "a": 1, "b": 3, None: 7})
    layouts = _engine.Layouts(["a", "b", None], sizes, {k: ("layout", k) for k in sizes})
    assert _engine.small_builds(layouts, config, 32) == 2
    assert _engine.small_builds(layouts, config, 1) == 0  # none is small
    shared = ("two-stage", ((30.0, 30.0),), None)
    two = _engine.Layouts(["a", "b"], sizes, {"a": shared, "b": shared, "big": shared})
    assert _engine.small_builds(two, config, 32) == _engine.TWO_STAGE_BUILD_COST
    # jobs of one setting at two α: a shared map once, a layout's own operator per α
    both = _engine.small_build_set(two, config, alpha=15.0)
    both |= _engine.small_build_set(two, config, alpha=15.2)
    assert _engine.build_cost(both) == _engine.TWO_STAGE_BUILD_COST
    own = _engine.small_build_set(layouts, config, alpha=15.0)
    own |= _engine.small_build_set(layouts, config, alpha=15.2)
    assert _engine.build_cost(own) == 4


def test_two_stage_layouts_share_one_build():
    """``--model aniso``'s two-stage map does not depend on where the samples lie: jittered
    captures (a layout each) of one set of pairs are one build, so a job of more of them than
    ``OPERATOR_MAX_BUILDS`` still gets operators."""
    config = aj.Config.recommended(budget="aniso204")  # filip2012 on log samples: two stages
    assert not config.linear
    n = _engine.OPERATOR_MAX_BUILDS + 1
    meas = [_meas(NAMES[k % len(NAMES)], "aniso204", jitter_deg=0.5, seed=k) for k in range(n)]
    layouts = _engine.job_layouts(meas, config)
    assert len(set(layouts.keys)) == n and len(set(layouts.builds.values())) == 1
    assert _engine.small_builds(layouts, config) == _engine.TWO_STAGE_BUILD_COST
    plan = _engine.plan_job(meas, config, layouts=layouts)
    assert {g["kind"] for g in plan.values()} == {"operator"} and len(plan) == n


def test_a_resumed_group_gets_the_batch_rows_and_bits_of_the_whole_run():
    """The command line's numpy operator (one GEMM per batch) rounds a table by its row in the
    batch: a resumed run (some tables kept, ``done``) puts each table at its row of the whole
    run (``order``) and gets its bits (issue 16; found by ``tests/test_kill.py``)."""
    from abrdf_jax import _cache
    from abrdf_jax._config import default_values

    config = aj.preset("recommended", "iso102")
    params = default_values(config, 15.0)
    meas = [
        _meas(n, noise=0.01, seed=k) for k, n in enumerate([*NAMES, *NAMES, *NAMES[:2]])
    ]  # 12 of one layout
    entry, _ = _cache.cached_entry(None, meas[0], config, params)

    def operator(c, p, template):
        return entry.apply

    run = dict(operator=operator, batch=8, min_group=12)
    whole = {}
    for idx, tables, path in _engine.reconstruct_many(meas, config, params, **run):
        assert path == "operator"
        whole.update(zip(idx, tables))
    keys = _engine.job_keys(meas, config, min_group=12)
    plan = _engine.plan_job(meas, config, min_group=12)  # one plan, passed to both: the same
    assert _engine.job_keys(meas, config, min_group=12, plan=plan) == keys
    for idx, tables, _ in _engine.reconstruct_many(meas, config, params, plan=plan, **run):
        for i, t in zip(idx, tables):
            np.testing.assert_array_equal(t, whole[i])
    kept = [0, 2, 3, 9, 10]  # 7 left: fewer than min_group, yet the operator's, at their rows
    done = [_engine.Done(keys[k]["layout"], keys[k]["group"], k, keys[k]["width"]) for k in kept]
    rest = [k for k in range(12) if k not in kept]
    parts = _engine.reconstruct_many(
        [meas[k] for k in rest], config, params, done=done, order=rest, **run
    )
    got = {}
    for idx, tables, path in parts:
        assert path == "operator"
        got.update((rest[i], t) for i, t in zip(idx, tables))
    assert sorted(got) == rest
    for k in rest:
        np.testing.assert_array_equal(got[k], whole[k], err_msg=f"measurement {k}")


def test_pipeline_groups_pad_the_last_batch_and_compile_once(monkeypatch):
    """Dense captures (spike-capped) and nonlinear rules take the pipeline; 5 measurements in
    batches of 2 trace it once (the last batch is padded to the same shape)."""
    config = aj.preset("paper", "aniso204")  # filip2012 on linear values: no operator
    params = aj.Params.default(config)
    # 31 samples per slice and slices padded to 40 knots: a shape no other test compiles
    meas = [
        aj.group_slices(
            aj.simulate_capture(materials.get_material(n), per_slice=31, seed=k), nmax=40
        )[0]
        for k, n in enumerate(NAMES)
    ]
    assert not any(_engine.operator_applies(config, m) for m in meas)
    traces = []
    real = _pipeline._reconstruct_core
    monkeypatch.setattr(
        _pipeline, "_reconstruct_core", lambda *a, **k: traces.append(1) or real(*a, **k)
    )
    parts = list(_engine.reconstruct_many(meas, config, params, batch=2))
    assert [i for i, _, _ in parts] == [[0, 1], [2, 3], [4]] and {p for *_, p in parts} == {
        "pipeline"
    }
    assert len(traces) == 1  # one trace (vmapped) for all three batches
    expected = np.asarray(aj.reconstruct(meas[4], config, params))
    # float32 rounding of the vmapped RBF solve, which depends on XLA's fusion of the batch
    # (about 1e-4 of the maximum here; docs/cache.md: ~3e-4 of the max against float64)
    np.testing.assert_allclose(parts[-1][1][0], expected, rtol=0, atol=5e-4 * expected.max())


def test_two_stage_rule_takes_the_operator():
    """filip2012 on the log of the samples (``--model aniso``) is an operator of two stages
    (``abrdf_jax/_centre_step.py``): ``reconstruct_many`` compiles it with
    ``nonlinear="two_stage"`` and matches the pipeline (float32 here, so its RBF solve's
    rounding: the bound of the test above)."""
    config = aj.preset("recommended", "aniso204")
    params = aj.Params.default(config)
    meas = [
        aj.group_slices(aj.simulate_capture(materials.get_material(n), noise=0.01, seed=k))[0]
        for k, n in enumerate(NAMES[:3])
    ]
    assert all(_engine.operator_applies(config, m) for m in meas)
    parts = list(_engine.reconstruct_many(meas, config, params, min_group=1))
    assert {p for *_, p in parts} == {"operator"}
    for idx, tables, _ in parts:
        for k, table in zip(idx, tables):
            want = np.asarray(aj.reconstruct(meas[k], config, params))
            np.testing.assert_allclose(table, want, rtol=0, atol=5e-4 * want.max())


def _folder(tmp_path, n=5, **kw):
    src = tmp_path / "in"
    src.mkdir()
    for k in range(n):
        s = aj.simulate_capture(
            materials.get_material(NAMES[k % len(NAMES)]), budget="iso102", noise=0.01, seed=k, **kw
        )
        io.write_samples_csv(src / f"m{k}.csv", s)
    return src


#: The RBF's diagonal-only model, fixed: these tests are about the operator store and the
#: pipeline's batches, which an automatic choice of an isotropic file (the bivariate model) skips.
ISO = ["--model", "iso"]
#: The same on linear values: its many small layouts take the pipeline (no two-stage form).
ISO_LINEAR = ["--model", "iso-linear"]


@pytest.mark.parametrize("engine", ["operator", "shared", "pipeline"])
def test_folder_resume_redoes_only_what_is_missing_or_torn(tmp_path, capsys, monkeypatch, engine):
    src, out = _folder(tmp_path), tmp_path / "out"
    model = ISO_LINEAR if engine == "pipeline" else ISO
    if engine != "operator":  # a job of many small layouts: five files of one layout, too few
        monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 0)
    assert main(["reconstruct", str(src), "-o", str(out), "-q", *model]) == 0
    first = {p.name: p.read_bytes() for p in out.iterdir()}
    record = json.loads((tmp_path / "out.model.json").read_text())
    want = "pipeline" if engine == "pipeline" else "operator"  # the shared form is an operator
    assert len(record["inputs"]) == 5 and {e["engine"] for e in record["inputs"]} == {want}
    assert {e["batch"]["small"] for e in record["inputs"]} == {engine == "operator"}
    (out / "m1.npz").unlink()
    (out / "m3.npz").write_bytes(first["m3.npz"][:100])  # torn
    capsys.readouterr()
    assert main(["reconstruct", str(src), "-o", str(out), "-q", "--resume", *model]) == 0
    text = capsys.readouterr().out
    assert "wrote 2 tables, 3 kept (--resume)" in text
    assert {p.name: p.read_bytes() for p in out.iterdir()} == first
    again = json.loads((tmp_path / "out.model.json").read_text())
    assert sorted(e["input"] for e in again["inputs"]) == sorted(
        e["input"] for e in record["inputs"]
    )
    assert main(["reconstruct", str(src), "-o", str(out), "-q", "--resume", *model]) == 0
    assert "all 5 tables are complete" in capsys.readouterr().out


def test_a_folder_of_few_layouts_builds_their_operators_and_resume_keeps_the_decision(
    tmp_path, capsys, monkeypatch
):
    """A folder's small layouts get operators where the whole block's are few, the pipeline
    where they are many (jittered captures: a layout each) on linear values (on the log of the
    samples they take the shared two-stage form, test below); a resumed run keeps the
    interrupted run's decision even when what is left would be few (the same bits)."""
    src = _folder(tmp_path, 4, jitter_deg=0.5)
    run = ["reconstruct", str(src), "-q", *ISO_LINEAR]  # (no shared form)

    def engines(out):
        record = json.loads((out.parent / (out.name + ".model.json")).read_text())
        return Counter(e["engine"] for e in record["inputs"])

    few = tmp_path / "few"
    assert main([*run, "-o", str(few)]) == 0
    assert engines(few) == {"operator": 4}  # four layouts of one file each: built
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 3)
    many = tmp_path / "many"
    assert main([*run, "-o", str(many)]) == 0
    assert engines(many) == {"pipeline": 4}
    whole = {p.name: p.read_bytes() for p in many.iterdir()}
    for name in ("m0.npz", "m2.npz"):
        (many / name).unlink()
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 2)  # two left: few, yet as recorded
    capsys.readouterr()
    assert main([*run, "-o", str(many), "--resume"]) == 0
    assert "wrote 2 tables, 2 kept (--resume)" in capsys.readouterr().out
    assert engines(many) == {"pipeline": 4}
    assert {p.name: p.read_bytes() for p in many.iterdir()} == whole


def test_a_folders_jittered_captures_share_a_second_stage_and_resume_keeps_it(tmp_path, capsys):
    """Within the small-layout rule a folder's jittered captures (a layout each, never met again)
    read their setting's shared second stage; its protocol captures (one layout, two files)
    keep their own operator; the store holds one map each, not an operator a capture; a
    resumed run gives the same bits (the lone layouts are counted with the kept files)."""
    src = _folder(tmp_path, 3, jitter_deg=0.5)
    for k in (3, 4):  # two protocol captures: one layout
        s = aj.simulate_capture(materials.get_material(NAMES[k]), noise=0.01, seed=k)
        io.write_samples_csv(src / f"m{k}.csv", s)
    out, cache = tmp_path / "out", tmp_path / "cache"
    run = ["reconstruct", str(src), "-o", str(out), "-q", "--cache-dir", str(cache)]
    run += ["--model", "iso"]
    assert main(run) == 0
    record = json.loads((tmp_path / "out.model.json").read_text())["inputs"]
    shared = {
        e["input"].rsplit("/", 1)[-1]: e["batch"]["group"]
        == _engine.group_id(("shared", e["batch"]["layout"]))
        for e in record
    }
    assert shared == {"m0.csv": True, "m1.csv": True, "m2.csv": True, "m3.csv": False,
                      "m4.csv": False}  # fmt: skip
    assert all(e["engine"] == "operator" and e["batch"]["small"] for e in record)
    assert len(list((cache / "operators").glob("*.npz"))) == 2  # the shared map, one operator
    whole = {p.name: p.read_bytes() for p in out.iterdir()}
    for name in ("m1.npz", "m3.npz"):
        (out / name).unlink()
    capsys.readouterr()
    assert main([*run, "--resume"]) == 0
    assert "wrote 2 tables, 3 kept (--resume)" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in out.iterdir()} == whole


def test_shared_second_stages_in_one_product_give_each_capture_its_own_bits(tmp_path, monkeypatch):
    """A folder's jittered captures (a call of ``reconstruct_many`` each: its own α) wait in one
    ``SharedStages`` and their second stages run as one product (``OperatorEntry.apply_many``):
    the tables equal, bit for bit, those of one product a capture, and those of the library's
    ``reconstruct_many`` (its own collector, its second stage built in memory) to float32
    rounding."""
    from abrdf_jax import _operator_entry

    src = _folder(tmp_path, 4, jitter_deg=0.5)
    calls = []
    real = _operator_entry.OperatorEntry.apply_many

    def counted(entries, ys):
        calls.append(len(entries))
        return real(entries, ys)

    monkeypatch.setattr(_operator_entry.OperatorEntry, "apply_many", staticmethod(counted))
    outs = []
    for rows in (_engine.SHARED_ROWS, 1):
        monkeypatch.setattr(_engine, "SHARED_ROWS", rows)
        out = tmp_path / f"out{rows}"
        argv = ["reconstruct", str(src), "-o", str(out), "-q", "--cache-dir", str(tmp_path / "c")]
        assert main([*argv, "--model", "iso"]) == 0
        outs.append({p.name: p.read_bytes() for p in out.iterdir()})
    assert calls == [4, 1, 1, 1, 1]  # one product for the four, then one each
    assert outs[0] == outs[1]
    config = aj.preset("recommended", "iso102")
    for k in range(4):
        s = io.read_samples_csv(src / f"m{k}.csv")
        meas, info = aj.group_slices(s)
        params = aj.Params.default(config, alpha_deg=info["alpha_deg"])
        plan = _engine.plan_job([meas], config, small=False)  # the shared form, no store
        ((_, tables, _),) = _engine.reconstruct_many([meas], config, params, plan=plan)
        table = io.read_table(tmp_path / f"out{_engine.SHARED_ROWS}" / f"m{k}.npz")
        np.testing.assert_allclose(table, tables[0], rtol=2e-5, atol=1e-6 * table.max())


def test_interrupted_folder_keeps_finished_tables_and_resumes_to_the_same_result(
    tmp_path, monkeypatch
):
    src = _folder(tmp_path)
    # the pipeline (as for a job of many small layouts), in batches of 2 in every run (XLA's
    # rounding depends on the batch shape, not on the partners)
    monkeypatch.setattr(_engine, "OPERATOR_MAX_BUILDS", 0)
    monkeypatch.setattr(_engine, "PIPELINE_BATCH", 2)
    whole = tmp_path / "whole"
    assert main(["reconstruct", str(src), "-o", str(whole), "-q", *ISO_LINEAR]) == 0
    real = _engine.reconstruct_many

    def killed_after_two_batches(meas, config, params, operator=None, **kw):
        for k, part in enumerate(real(meas, config, params, operator=operator, **kw)):
            if k == 2:
                raise KeyboardInterrupt
            yield part

    monkeypatch.setattr(_engine, "reconstruct_many", killed_after_two_batches)
    monkeypatch.setattr(reconstruct, "RECORD_EVERY", 0.0)  # the record after every batch
    out = tmp_path / "out"
    assert main(["reconstruct", str(src), "-o", str(out), "-q", *ISO_LINEAR]) == 130
    record = json.loads((tmp_path / "out.model.json").read_text())
    listed = {e["input"] for e in record["inputs"]}
    assert 0 < len(listed) < 5  # the finished batches, never a file that is not complete
    for e in record["inputs"]:
        table = io.read_table(out / (e["input"].rsplit("/", 1)[-1][:-4] + ".npz"))
        assert table.shape == (81, 81, 3)
    assert not [p for p in out.iterdir() if p.suffix != ".npz"]  # no temporary file left
    monkeypatch.setattr(_engine, "reconstruct_many", real)
    assert main(["reconstruct", str(src), "-o", str(out), "-q", "--resume", *ISO_LINEAR]) == 0
    for p in whole.iterdir():
        assert (out / p.name).read_bytes() == p.read_bytes()


def test_resume_needs_a_folder(tmp_path, capsys):
    src = _folder(tmp_path, 1)
    assert (
        main(["reconstruct", str(src / "m0.csv"), "-o", str(tmp_path / "r.npz"), "--resume"]) == 2
    )
    assert "--resume needs an output folder" in capsys.readouterr().err


@pytest.mark.parametrize("where", ["off", "file"])
def test_cache_off_or_unusable_still_reconstructs(tmp_path, capsys, where):
    src = _folder(tmp_path, 1)
    cache = "off"
    if where == "file":  # a file where the cache folder should be: a warning, no failure
        (tmp_path / "c").write_text("x")
        cache = str(tmp_path / "c")
    out = tmp_path / "r.npz"
    assert (
        main(["reconstruct", str(src / "m0.csv"), "-o", str(out), "--cache-dir", cache, *ISO]) == 0
    )
    err = capsys.readouterr().err
    # the operator store's warning (a cold iso102 file builds in numpy: JAX's compilation
    # cache is not touched)
    assert ("running without it" in err and str(tmp_path / "c") in err) == (where == "file")
    assert io.read_table(out).shape == (81, 81, 3)


def test_a_folder_read_in_blocks_gives_the_same_tables_and_checks_every_file_first(
    tmp_path, monkeypatch
):
    """A folder larger than ``BLOCK`` files is checked whole, then read again block by block
    (bounded memory, docs/stability.md "Load"): the same tables and record as one block, and a
    bad file in the last block still fails the run before anything is written."""
    src = _folder(tmp_path, 3)
    monkeypatch.setattr(_engine, "PIPELINE_BATCH", 2)  # the same batch shapes in both runs
    whole = tmp_path / "whole"
    assert main(["reconstruct", str(src), "-o", str(whole), "-q"]) == 0
    monkeypatch.setattr(_common, "BLOCK", 2)  # 3 files: blocks of 2 and 1
    out = tmp_path / "out"
    assert main(["reconstruct", str(src), "-o", str(out), "-q"]) == 0
    for p in whole.iterdir():
        if p.name == "m2.npz":  # alone in its block, so in a batch of one: the bivariate map
            # in factors (float64), not the layout's float32 matrix: within float32 rounding
            want = io.read_table(p)
            np.testing.assert_allclose(
                io.read_table(out / p.name), want, rtol=1e-5, atol=1e-7 * want.max()
            )
        else:
            assert (out / p.name).read_bytes() == p.read_bytes(), p.name

    def entries(name):
        doc = json.loads((tmp_path / f"{name}.model.json").read_text())
        return [{k: v for k, v in e.items() if k != "seconds"} for e in doc["inputs"]]

    assert entries("out") == entries("whole")
    (src / "m9.csv").write_text("theta_i,phi_i,theta_v,phi_v,r,g,b\n30,0,30,x,1,1,1\n")
    bad = tmp_path / "bad"
    assert main(["reconstruct", str(src), "-o", str(bad), "-q"]) == 2
    assert not bad.exists() and not (tmp_path / "bad.model.json").exists()


def test_long_stages_say_so_and_quick_ones_do_not(tmp_path, monkeypatch, capsys):
    """Progress on long work (docs/stability.md, "Load"): a folder shows a bar while its files
    are read; one file says when its reading is large and when a stage runs long (here every
    file is large and every stage long), and ``-q`` or a quick stage says nothing."""
    from abrdf_jax.cli import _progress

    src = _folder(tmp_path, 2)
    monkeypatch.setattr(_progress, "READ_BAR_DELAY", 0.0)  # shown at once, not after 1 s
    assert main(["reconstruct", str(src), "-o", str(tmp_path / "out")]) == 0
    assert "read: 100%" in capsys.readouterr().err
    one = ["reconstruct", str(src / "m0.csv"), "-o", str(tmp_path / "r.npz")]
    assert main(one) == 0
    assert "m0.csv: choosing the model" not in capsys.readouterr().err  # quick: nothing
    monkeypatch.setattr(_progress, "BIG_FILE_BYTES", 0)
    monkeypatch.setattr(_progress, "SLOW_STAGE_S", 0.0)
    assert main(one) == 0
    err = capsys.readouterr().err
    for said in ("reading", "choosing the model (102 samples) ...", "choosing the model: done in"):
        assert said in err, err
    assert main([*one, "-q"]) == 0
    assert "abrdf-jax: " not in capsys.readouterr().err.replace("abrdf-jax: replacing", "")


class _Shapes:
    """An ``operator_only`` model (as the bivariate and learned ones) that records the batch
    shapes its maps are called with."""

    operator_only = True

    def __init__(self):
        self.seen = []

    def operator(self, params, template):
        def apply(y):
            self.seen.append(len(y))
            return np.zeros((len(y), 81, 81, 3), np.float32)

        return apply


def test_numpy_maps_are_not_padded_beyond_the_jobs_group():
    """A numpy map compiles nothing: a layout that one capture holds (every jittered one) is
    one row, a layout of three files three rows, not a padded batch of OPERATOR_BATCH; a
    resumed run (the others done) keeps the shape of the whole job's group (the same bits)."""
    mat = materials.get_material("ggx-plastic")
    jittered = [
        aj.group_slices(aj.simulate_capture(mat, budget="iso102", jitter_deg=0.5, seed=k))[0]
        for k in range(2)
    ]
    same = [aj.sample(mat, aj.Config(budget="iso102"), as_measurements=True)] * 3
    meas = jittered + same
    model = _Shapes()
    out = list(_engine.reconstruct_many(meas, model, None))
    assert sorted(model.seen) == [1, 1, 3] and sum(len(i) for i, _, _ in out) == 5
    assert {p for _, _, p in out} == {"operator"}
    keys = _engine.job_keys(meas, model, min_group=1)
    done = [_engine.Done(order=k, **keys[k]) for k in (2, 3)]  # two of the three were done
    resumed = _Shapes()
    rest = [0, 1, 4]
    list(_engine.reconstruct_many([meas[k] for k in rest], resumed, None, done=done, order=rest))
    assert sorted(resumed.seen) == [1, 1, 3]  # the last file's row in a batch of its group's 3
