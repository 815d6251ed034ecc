"""The adaptive estimator and the trimmed controller on the simulated rig, offline.

The demo's "Done when" figures without timing noise: on the rig_truth plant (μ +6 %, steeper
temperature decay, coulomb spline law: not the estimator's model), every plateau of the
quick demo profile within 2 % of the request, ±10 % all the time, overshoot ≤ 5 %; and the
feed-forward path (no adaptation, no trim) still reports its own, larger, plateau error.
"""

import math

import numpy as np
import pytest

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import reference_torque
from clutch_ros.model.adaptation import AdaptationSettings
from clutch_ros.offline.closed_loop import run_closed_loop
from clutch_ros.rig import RigPlant
from clutch_ros.rig.request_profile import demo_profile

W10 = 10 * 2 * math.pi / 60  # [rad/s]


@pytest.fixture(scope="module")
def setup():
    params = load_params(preset_path("flexiforce_8"))
    rated = float(reference_torque(params, 40e5, 35.0, W10))
    return params, rated, demo_profile(rated, quick=True)


@pytest.fixture(scope="module")
def adaptive(setup):
    params, rated, profile = setup
    return run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile,
                           adaptation=AdaptationSettings(), rated_torque=rated)


@pytest.fixture(scope="module")
def feed_forward(setup):
    params, rated, profile = setup
    return run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile,
                           rated_torque=rated)


def test_adaptive_loop_meets_the_targets(adaptive):
    print(f"adaptive: sse {adaptive.steady_state_error:.4f}, within "
          f"{adaptive.within_10pct:.4f}, worst {adaptive.worst_overshoot:.4f}")
    assert adaptive.steady_state_error <= 0.02
    assert adaptive.within_10pct >= 0.99
    assert adaptive.worst_overshoot <= 1.05
    # the pressure never left the limits; the trim did work; the scale learned mu +6 %
    assert np.all((adaptive.pressure_command >= 0.0) & (adaptive.pressure_command <= 40e5))
    assert np.abs(adaptive.trim_pressure).max() > 0.0
    assert 1.02 < adaptive.friction_scale[-1] < 1.08


def test_feed_forward_reports_its_own_larger_error(adaptive, feed_forward):
    print(f"feed-forward: sse {feed_forward.steady_state_error:.4f}")
    assert math.isfinite(feed_forward.steady_state_error)
    assert feed_forward.steady_state_error > 2 * adaptive.steady_state_error
    assert np.all(feed_forward.trim_pressure == 0.0) and np.all(feed_forward.friction_scale == 1)
