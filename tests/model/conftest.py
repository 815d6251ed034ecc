"""Fixtures of the model-core tests: presets and a small helper to change parameters."""

from pathlib import Path

import pytest

from clutch_ros.config.params_file import load_params

PARAMS_DIR = Path(__file__).resolve().parents[2] / "params"
PRESETS = ("flexiforce_8", "test_a_organic13", "test_b_sintered10", "rig_truth")


@pytest.fixture(scope="session")
def flexiforce():
    """Return the default estimator preset (8 lamellas, ff_t, Table 7 at 10 rpm)."""
    return load_params(PARAMS_DIR / "flexiforce_8.yaml")


@pytest.fixture(scope="session")
def truth():
    """Return the simulated rig's truth plant (coulomb law)."""
    return load_params(PARAMS_DIR / "rig_truth.yaml")


@pytest.fixture(scope="session")
def presets():
    """Return all shipped presets by name."""
    return {name: load_params(PARAMS_DIR / f"{name}.yaml") for name in PRESETS}
