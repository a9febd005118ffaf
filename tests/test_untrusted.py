"""Untrusted files are read without executing anything (issue 16, part): no reader of the
package unpickles, so a table or data file holding a pickled object is refused."""

import re
from pathlib import Path

import numpy as np
import pytest

from abrdf_jax import io
from abrdf_jax._errors import InputError

PACKAGE = Path(__file__).resolve().parents[1] / "abrdf_jax"


def test_every_np_load_in_the_package_refuses_pickles():
    calls = []
    for path in PACKAGE.rglob("*.py"):
        for m in re.finditer(r"np\.load\((.*)", path.read_text()):
            calls.append((path.name, m.group(1)))
    assert calls, "no np.load found: the check would be empty"
    assert all("allow_pickle=False" in rest for _, rest in calls), calls


def test_a_table_holding_a_pickled_object_is_refused(tmp_path):
    p = tmp_path / "evil.npz"
    np.savez(p, table=np.array([{"run": "code"}], dtype=object))
    with pytest.raises(InputError, match="evil.npz"):
        io.read_table(p)
