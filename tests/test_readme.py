"""The README's Python examples run as written (they end in an accuracy check)."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_blocks_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 2
    namespace: dict = {}
    for code in blocks:
        exec(compile(code, str(README), "exec"), namespace)  # noqa: S102
    assert namespace["errors"]["de76"] < 12
    grads = namespace["grads"]
    for g in (grads.alpha, grads.widths, grads.reg):
        assert np.all(np.isfinite(np.asarray(g)))
    assert float(abs(grads.alpha)) > 0
