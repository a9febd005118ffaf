"""Smoke test of the speed/accuracy suite (``python -m benchmarks --smoke``): it runs and writes valid output.

Three configurations (the compiled operator of the paper's method, the PCA peer, mean fill) on two
MERL test materials and the throughput part at batch sizes 1 and 10; the JSON must parse, carry the
machine/threads/versions/load blocks and one complete point per configuration with finite figures,
the Pareto flags must agree with the points, and the throughput block's figures must be consistent
(rates from the times, the roofline fraction from the flops). Speed is not checked.
"""

import json
import math

import pytest

from benchmarks import suite

POINT_KEYS = {
    "name",
    "group",
    "dataset",
    "layout",
    "budget",
    "n_samples",
    "dtype",
    "n_materials",
    "seconds_per_abrdf",
    "batch_seconds",
    "compile_seconds",
    "setup_seconds",
    "repeats",
    "finite",
    "de76",
    "logerr",
    "de2000",
    "rmse8",
    "psnr",
    "per_material",
    "pareto_de76",
    "pareto_logerr",
}


def test_suite_smoke_writes_valid_json(data_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("ABRDF_DATA", str(data_dir))
    suite.main(["--smoke", "--out", str(tmp_path)], log=lambda *a: None)
    payload = json.loads((tmp_path / "suite_smoke.json").read_text())
    assert payload["mode"] == "smoke"
    for block in ("machine", "threads", "versions", "layouts", "materials", "pareto"):
        assert payload[block], block
    assert payload["versions"]["jax"] and payload["threads"]["cpu_count"]
    names = {e.name for e in suite.REGISTRY.values() if "smoke" in e.modes}
    points = payload["points"]
    assert {p["name"] for p in points} == names and len(points) == len(names) == 3
    assert "operator paper iso102" in names
    for p in points:
        assert "error" not in p, p.get("error")
        assert POINT_KEYS <= set(p), POINT_KEYS - set(p)
        assert p["n_materials"] == 2 and p["dataset"] == "merl-test" and p["finite"]
        assert len(p["per_material"]["de76"]) == 2
        for key in ("seconds_per_abrdf", "de76", "logerr", "de2000", "rmse8", "psnr"):
            assert math.isfinite(p[key]), (p["name"], key)
        # A time was recorded (a positive number: the schema), never bounded: speed is the suite's
        # output, not something a test checks.
        assert p["seconds_per_abrdf"] > 0 and p["de76"] >= 0 and p["logerr"] >= 0
    # the Pareto front: nobody on it is beaten in both time and error, everybody off it is
    for metric in ("de76", "logerr"):
        front = set(payload["pareto"]["merl-test"][metric])
        assert front == {p["name"] for p in points if p[f"pareto_{metric}"]}
        for p in points:
            beaten = any(
                q is not p
                and q["seconds_per_abrdf"] <= p["seconds_per_abrdf"]
                and q[metric] <= p[metric]
                for q in points
            )
            assert (p["name"] not in front) == beaten, (metric, p["name"])
    assert len(payload["load_average_before"]) == len(payload["load_average_after"]) == 3
    # the throughput part: every batch size timed (a positive time recorded, no bound on it), and the
    # rates derived consistently from those times
    tp = payload["throughput"]
    assert tp["batches"] == [1, 10] and tp["gemm_square"]["gflops"] > 0
    nb = tp["gemm_same_shape_numpy"]  # the same GEMM in numpy's BLAS, beside XLA's
    assert nb["shape"] == tp["gemm_same_shape"]["shape"] == [30, 102, 6561]
    assert math.isclose(nb["gflops"], 2.0 * 30 * 102 * 6561 / nb["seconds"] / 1e9, rel_tol=1e-9)
    pre = tp["presets"]["paper"]
    assert pre["matrix_shape"] == [6561, 102] and pre["n_inputs"] == 102
    for row, b in zip(pre["rows"], tp["batches"]):
        assert row["batch"] == b and row["seconds"] > 0
        assert math.isclose(row["abrdfs_per_second"], b / row["seconds"], rel_tol=1e-9)
        flops = 2.0 * 6561 * 102 * 3 * b
        assert math.isclose(
            row["fraction_of_roofline"],
            flops / row["seconds"] / 1e9 / tp["gemm_square"]["gflops"],
            rel_tol=1e-9,
        )
    assert pre["latency_seconds"] == pre["rows"][0]["seconds"]
    assert set(tp["targets"]["presets"]) == {"paper"} and tp["targets"]["lines"]
    assert (tmp_path / "speed_accuracy_smoke.png").stat().st_size > 10_000
    assert (tmp_path / "throughput_batch_smoke.png").stat().st_size > 10_000
    md = (tmp_path / "suite_smoke.md").read_text()
    assert "| configuration |" in md and "| batch |" in md and "in numpy's" in md
    # --replot rebuilds the table from the stored JSON alone
    (tmp_path / "suite_smoke.md").unlink()
    suite.main(["--smoke", "--out", str(tmp_path), "--replot", "--no-plot"], log=lambda *a: None)
    assert (tmp_path / "suite_smoke.md").read_text() == md
    # --update reruns one entry and merges it: same points (one replaced), the throughput part kept
    suite.main(
        ["--smoke", "--out", str(tmp_path), "--update", "--only", "mean fill iso102", "--no-plot"],
        log=lambda *a: None,
    )
    merged = json.loads((tmp_path / "suite_smoke.json").read_text())
    assert sorted(p["name"] for p in merged["points"]) == sorted(p["name"] for p in points)
    assert merged["throughput"] == tp and [u["entries"] for u in merged["updates"]] == [
        ["mean fill iso102"]
    ]
    fill = [p for p in merged["points"] if p["name"] == "mean fill iso102"]
    assert fill[0]["de76"] == next(p["de76"] for p in points if p["name"] == "mean fill iso102")


def test_captures_smoke_writes_valid_json(tmp_path):
    """``python -m benchmarks.captures`` on the two quick anisotropic materials (analytic: no
    data needed) and two capture kinds: one folder call of the CLI per kind, figures for the
    package, the scipy peer and mean fill (or "n/a" with a reason), the targets, the charts."""
    from benchmarks import captures

    argv = ["--quick", "--sets", "aniso", "--kinds", "protocol,gap-20", "--out", str(tmp_path)]
    captures.main(argv, log=lambda *a: None)
    payload = json.loads((tmp_path / "captures_quick.json").read_text())
    assert payload["mode"] == "quick" and payload["machine"]["cpu_count"]
    assert len(payload["load_average_before"]) == len(payload["load_average_after"]) == 3
    assert "benchmarks.captures" in payload["commands"]["benchmark"]
    block = payload["sets"]["aniso"]
    assert block["budget"] == "aniso204" and len(block["materials"]) == 2
    assert list(block["kinds"]) == ["protocol", "gap-20"]
    for kind, r in block["kinds"].items():
        cli = r["cli"]
        assert cli["command"].startswith("python -m abrdf_jax.cli reconstruct aniso/" + kind)
        assert isinstance(cli["exit_code"], int) and cli["seconds"] > 0 and cli["warnings"] >= 0
        assert cli["ok"] == (cli["exit_code"] == 0 and not cli["invalid"])
        assert set(r["n_samples"]) == {f"{m}" for m in block["materials"]}
        for method in ("package", "scipy", "mean_fill"):
            res = r[method]
            if "n/a" in res:  # never a silent gap: the reason is recorded
                assert res["n/a"], (kind, method)
                continue
            assert set(res["per_material"]) == set(block["materials"])
            for key in ("de76", "de76_median", "logerr", "logerr_median", *captures.SPLIT):
                assert math.isfinite(res[key]) and res[key] >= 0, (kind, method, key)
            share = 1296 / 6561  # the protocol's pairs: 36 x 36 of the 81 x 81 cells
            for m in res["per_material"].values():  # the split's cells add up to the whole
                whole = share * m[captures.SPLIT[0]] + (1 - share) * m[captures.SPLIT[1]]
                assert whole == pytest.approx(m["de76"], rel=1e-4), (kind, method)
    assert block["kinds"]["protocol"]["cli"]["exit_code"] == 0  # the ideal capture runs today
    assert block["kinds"]["protocol"]["n_samples"]["ggx-aniso-metal"] == 204
    targets = payload["targets"]
    assert [t["target"] for t in targets][0].startswith("every capture kind")
    assert all(isinstance(t["pass"], bool) for t in targets)
    md = (tmp_path / "captures_quick.md").read_text()
    assert "| capture |" in md and "## Targets" in md and "gap-20" in md
    assert "Where the package's error lies" in md and "unless they also improve" in md
    for chart in ("captures_density_quick.png", "captures_noise_quick.png"):
        assert (tmp_path / chart).stat().st_size > 10_000
