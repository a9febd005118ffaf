"""Shared test set-up: float64, strict promotion for the numerical core, the shared data folder, seeds."""

import gc
import os
import sys
from pathlib import Path

# The tests check numbers, not speed: XLA compiles their programs at its lowest backend
# optimisation level, without LLVM's expensive passes and with the CPU backend's older
# (non-MLIR) fusion emitters (the same operations; compiling is most of the suite's time, a few
# run-heavy tests are slower: `pytest --durations`; like for like, docs/notes.md "Testing":
# test_transforms + test_engine faster with the first two; the emitters: docs/notes.md
# "Where the suite's time goes", the command and figures). Subprocesses inherit it. A user's
# XLA_FLAGS wins.
os.environ.setdefault(
    "XLA_FLAGS",
    "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true "
    "--xla_cpu_use_fusion_emitters=false",
)

import jax  # noqa: E402 - after XLA_FLAGS
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# The caches of the command line (abrdf_jax._cache) go to a folder of this test session, never
# to the user's ~/.cache; subprocesses inherit it. A test of the caches sets its own.
if "ABRDF_JAX_CACHE_DIR" not in os.environ:
    import atexit
    import shutil
    import tempfile

    os.environ["ABRDF_JAX_CACHE_DIR"] = tempfile.mkdtemp(prefix="abrdf-jax-test-cache-")
    os.environ["ABRDF_JAX_TEST_SESSION_CACHE"] = os.environ["ABRDF_JAX_CACHE_DIR"]
    atexit.register(shutil.rmtree, os.environ["ABRDF_JAX_CACHE_DIR"], True)
# That folder's compilation cache (xla/) is on in the test processes too, from the start: a
# program compiled once in this session (by either pytest-xdist worker, a test in this process
# or an `abrdf-jax` subprocess, which use the same folder) is loaded, not compiled, by the
# others. Only for the session's own folder (the xdist workers inherit the variables), never a
# user's cache.
SESSION_CACHE = os.environ.get("ABRDF_JAX_TEST_SESSION_CACHE")
if SESSION_CACHE is None or SESSION_CACHE != os.environ["ABRDF_JAX_CACHE_DIR"]:
    SESSION_CACHE = None

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # for tests.scipy_oracle and the benchmarks that the smoke tests run
DATA_DIR = Path(os.environ.get("ABRDF_DATA", REPO.parent / "shared" / "data"))
SEED = int(os.environ.get("ABRDF_TEST_SEED", "0"))

# Test modules of the numerical core: they run with strict dtype promotion (no silent float32 ->
# float64 or int -> float mixing) and rank promotion raising (no silent broadcasting of a missing
# axis), so an implicit cast or broadcast in the package fails here instead of costing precision.
STRICT_MODULES = {
    "test_transforms",
    "test_subspace",
    "test_interp1d",
    "test_rbf",
    "test_grid",
    "test_pipeline",
    "test_operator",
}


@pytest.hookimpl(tryfirst=True, optionalhook=True)  # pytest-xdist's hook: none without it
def pytest_xdist_make_scheduler(config, log):
    """``-n 2`` without ``--dist``: pytest-xdist's work-stealing scheduler instead of ``load``.
    ``load`` hands out the tests one by one to whichever worker is free, so both workers run
    parts of every module and each builds the module's fixtures and compiles its functions;
    ``worksteal`` gives each worker a contiguous half of the collection and lets an idle worker
    take the far end of the other's queue, so a module mostly stays on one worker."""
    args = config.invocation_params.args
    if config.getvalue("dist") != "load" or any(str(a).startswith(("--dist", "-d")) for a in args):
        return None
    try:
        from xdist.scheduler import WorkStealingScheduling
    except ImportError:  # pytest-xdist before 3.2
        return None
    return WorkStealingScheduling(config, log)


# ABRDF_TEST_COMPILE_LOG=FILE: each test's JAX tracing, lowering and XLA compile seconds and its
# number of compiles (this process only, set-up included; a CLI subprocess is not counted) are
# appended to FILE as tab-separated lines, to see where the suite's time goes (docs/notes.md).
_COMPILE_LOG = os.environ.get("ABRDF_TEST_COMPILE_LOG")
_COMPILE_TIMES: dict[str, float] = {}
if _COMPILE_LOG:
    from jax import monitoring

    def _on_duration(event: str, duration: float, **_) -> None:
        if event.startswith("/jax/core/compile/"):
            key = event.rsplit("/", 1)[1]
            _COMPILE_TIMES[key] = _COMPILE_TIMES.get(key, 0.0) + duration
            if key == "backend_compile_duration":
                _COMPILE_TIMES["n_compiles"] = _COMPILE_TIMES.get("n_compiles", 0) + 1

    monitoring.register_event_duration_secs_listener(_on_duration)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _COMPILE_TIMES.clear()
        yield
        t = _COMPILE_TIMES
        with open(_COMPILE_LOG, "a") as f:
            f.write(
                f"{item.nodeid}\t{t.get('jaxpr_trace_duration', 0):.2f}"
                f"\t{t.get('jaxpr_to_mlir_module_duration', 0):.2f}"
                f"\t{t.get('backend_compile_duration', 0):.2f}\t{int(t.get('n_compiles', 0))}\n"
            )


def pytest_report_header(config):
    return [f"abrdf_jax test seed: {SEED} (override with ABRDF_TEST_SEED)", f"data: {DATA_DIR}"]


@pytest.fixture(autouse=True)
def _strict_promotion(request):
    """Strict dtype and rank promotion for the modules in :data:`STRICT_MODULES`."""
    if request.module.__name__.rpartition(".")[2] not in STRICT_MODULES:
        yield
        return
    with jax.numpy_dtype_promotion("strict"), jax.numpy_rank_promotion("raise"):
        yield


def _session_compilation_cache() -> None:
    """Turn the session's compilation cache on (again) in this process, unless it is on."""
    if SESSION_CACHE is None:
        return
    from abrdf_jax._compilation_cache import XLA, enable_compilation_cache

    if jax.config.jax_compilation_cache_dir != str(Path(SESSION_CACHE) / XLA):
        enable_compilation_cache(Path(SESSION_CACHE))


_session_compilation_cache()


@pytest.fixture(autouse=True)
def _compilation_cache_back_on():
    """A test of the caches (or a CLI call with its own --cache-dir) may point JAX's compilation
    cache elsewhere or turn it off: the next test finds the session's again."""
    yield
    _session_compilation_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Each module's compiled programs are released after it (``jax.clear_caches``). Every XLA
    executable holds a few memory mappings of its own: one process running the whole suite
    (``pytest`` without ``-n``) passed 24,000 mappings and 5.5 GB at a third of the suite (a
    scratch monitor of ``/proc/PID/maps``), on
    course for the kernel's limit (``vm.max_map_count``, 65,530 here), and crashed inside XLA's
    compiler at 89 % (docs/notes.md). A program a later module needs again is loaded from the
    session's compilation cache, not compiled."""
    yield
    jax.clear_caches()
    gc.collect()


@pytest.fixture
def rng():
    return np.random.default_rng(SEED)


@pytest.fixture(scope="session")
def data_dir():
    """The shared data folder; missing is a skip locally and a failure under CI=true."""
    if not (DATA_DIR / "merl-nbrdf" / "tables81.npz").exists():
        msg = f"shared data not found at {DATA_DIR} (set ABRDF_DATA)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return DATA_DIR
