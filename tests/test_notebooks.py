"""Execute every notebook in ``notebooks/`` so that the committed examples cannot rot.

Each notebook is read, executed in memory (the file on disk is never rewritten) with nbclient in a
kernel that runs this interpreter (``sys.executable``: the venv where ``abrdf_jax`` is installed),
with ``notebooks/`` as the working directory and 300 s per cell; any cell error fails the test with
the cell's source and traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel  # noqa: E402
from jupyter_client.manager import KernelManager  # noqa: E402
from nbclient.exceptions import CellExecutionError  # noqa: E402

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
CELL_TIMEOUT_S = 300
KERNEL_NAME = "python3"


def _runs_this_python(argv: list[str]) -> bool:
    """Whether a kernel command line starts this interpreter.

    jupyter_client replaces a bare ``python``/``python3``/``python3.X`` by ``sys.executable``
    when it launches the kernel, so those count as this interpreter too.
    """
    if not argv:
        return False
    major, minor = sys.version_info[:2]
    if argv[0] in {"python", f"python{major}", f"python{major}.{minor}"}:
        return True
    try:
        return Path(argv[0]).resolve() == Path(sys.executable).resolve()
    except OSError:
        return False


def _kernel_manager(tmp_path: Path) -> KernelManager:
    """A kernel manager for ``python3`` if that spec runs this interpreter, else a private spec.

    A ``python3`` spec found elsewhere on the Jupyter path (a user-level or system install) would
    start a Python without ``abrdf_jax``; in that case a spec pointing at ``sys.executable`` is
    written under ``tmp_path`` and used instead.
    """
    try:
        spec = KernelSpecManager().get_kernel_spec(KERNEL_NAME)
        if _runs_this_python(spec.argv):
            return KernelManager(kernel_name=KERNEL_NAME)
    except NoSuchKernel:
        pass
    name = "abrdf-jax-test"
    spec_dir = tmp_path / "kernels" / name
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(
        json.dumps(
            {
                "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": f"Python ({sys.executable})",
                "language": "python",
            }
        )
    )
    ksm = KernelSpecManager(kernel_dirs=[str(tmp_path / "kernels")], ensure_native_kernel=False)
    return KernelManager(kernel_name=name, kernel_spec_manager=ksm)


def test_notebooks_found():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


def _run_probe(km: KernelManager) -> str:
    """Run a one-cell notebook that imports abrdf_jax and prints the kernel's interpreter."""
    from nbformat.v4 import new_code_cell, new_notebook

    nb = new_notebook(cells=[new_code_cell("import sys, abrdf_jax; print(sys.executable)")])
    resources = {"metadata": {"path": str(NOTEBOOK_DIR)}}
    nbclient.NotebookClient(nb, km=km, timeout=60, resources=resources).execute()
    return "".join(o.get("text", "") for o in nb.cells[0].outputs).strip()


@pytest.mark.parametrize("fallback", [False, True], ids=["python3-spec", "private-spec"])
def test_kernel_runs_this_python(tmp_path, monkeypatch, fallback):
    if fallback:  # a spec name that does not exist forces the private sys.executable spec
        monkeypatch.setattr(sys.modules[__name__], "KERNEL_NAME", "no-such-kernel-abrdf")
    km = _kernel_manager(tmp_path)
    assert _runs_this_python(km.kernel_spec.argv), km.kernel_spec.argv
    assert Path(_run_probe(km)).resolve() == Path(sys.executable).resolve()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path: Path, tmp_path: Path, monkeypatch):
    # The notebooks' coarse settings (fewer grid points and steps, the same code): the kernel
    # inherits the environment.
    monkeypatch.setenv("ABRDF_NOTEBOOK_QUICK", "1")
    nb = nbformat.read(path, as_version=4)  # in memory only: the committed file is never rewritten
    km = _kernel_manager(tmp_path)
    client = nbclient.NotebookClient(
        nb,
        km=km,
        timeout=CELL_TIMEOUT_S,
        allow_errors=False,
        resources={"metadata": {"path": str(NOTEBOOK_DIR)}},
    )
    try:
        client.execute()
    except CellExecutionError as exc:  # exc holds the cell's source and traceback
        pytest.fail(f"{path.name}: a cell raised\n{exc}", pytrace=False)
    errors = [
        (i, out.get("ename"), out.get("evalue"))
        for i, cell in enumerate(nb.cells)
        if cell.cell_type == "code"
        for out in cell.get("outputs", [])
        if out.get("output_type") == "error"
    ]
    assert not errors, f"{path.name}: error outputs in cells {errors}"
