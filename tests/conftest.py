"""Shared test set-up: float64 for the numerical tests, the shared data folder, seeds."""

import os
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # for tests.scipy_oracle and the benchmarks that the smoke tests run
DATA_DIR = Path(os.environ.get("ABRDF_DATA", REPO.parent / "shared" / "data"))
SEED = int(os.environ.get("ABRDF_TEST_SEED", "0"))


def pytest_report_header(config):
    return [f"abrdf_jax test seed: {SEED} (override with ABRDF_TEST_SEED)", f"data: {DATA_DIR}"]


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
