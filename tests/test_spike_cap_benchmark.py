"""``benchmarks.spike_cap``'s paired comparison of two settings (the rule that keeps a default)."""

import numpy as np
import pytest

from benchmarks.spike_cap import markdown, paired


def _row(setting, per_kind):
    per = {k: list(v) for k, v in per_kind.items()}
    mean = {k: float(np.mean(v)) for k, v in per.items()}
    return {"setting": setting, "mean": mean, "per_material": per,
            "overall": float(np.mean(list(mean.values())))}  # fmt: skip


def test_paired_difference_mean_standard_error_and_count():
    a = _row("a", {"protocol": [2.0, 3.0, 4.0], "dense-100": [2.0, 1.0, 4.0]})
    b = _row("b", {"protocol": [1.0, 3.0, 5.0], "dense-100": [1.0, 3.0, 3.0]})
    d = paired(a, b)
    diff = np.array([1.0, -1.0, 0.0])  # per material: mean over the kinds of a − b
    assert d["mean"] == pytest.approx(diff.mean())
    assert d["se"] == pytest.approx(diff.std(ddof=1) / np.sqrt(3))
    assert (d["lower"], d["n"]) == (1, 3)


def test_markdown_reports_the_paired_difference_when_the_lowest_is_not_the_default():
    import abrdf_jax as aj

    kinds = ("protocol", "dense-100", "jitter-0.5", "noise-5", "extra-pairs")
    default = str(aj.Config().spike_cap)
    rows = [_row(default, {k: [3.0, 2.0] for k in kinds}),
            _row("(0.5, 1.0)", {k: [2.0, 1.5] for k in kinds})]  # fmt: skip
    payload = {"command": "x", "n_materials": 2, "load_before": [0], "load_after": [0],
               "seconds": 1.0, "chosen": "(0.5, 1.0)"}  # fmt: skip
    text = markdown(rows, payload)
    assert "higher by 0.7500 ± 0.2500" in text and "lower on 0 of 2" in text
    payload["chosen"] = default
    assert "Paired" not in markdown(rows, payload)
