"""The first step, before any torque has been learned, over the preset's uncertainty of μ.

Offline and deterministic (:func:`clutch_ros.offline.closed_loop.run_closed_loop`: the truth
plant at 1 kHz, the adaptive estimator, the controller; no wall clock, no ROS), on the
profile of the demo's first step: 1.5 s at 0 N m with the slip established, then a step to
half the rated torque held 2 s (the quick demo's).

What "the preset's uncertainty of μ" is: the presets state μ_ref without a tolerance; the
uncertainty the suite ships with is the adaptation's prior of the friction scale,
``AdaptationSettings.initial_std`` = 0.2 (1 σ). The grid covers ±2 σ (μ from 0.6 to 1.4 x
the estimator preset's μ_ref) plus the shipped rig_truth's +6 %; the rig's other
differences from the model (coulomb spline law, damping, static peak, oil film) stay in.
Why a grid rather than hypothesis: each point is a 3.5 s closed loop (~1 s of CPU) and the
figure is smooth in μ, so nine fixed points, denser where the trim's reach ends (0.9, 1.1,
1.2), show more than random draws at the same cost, and every run sees the same points.

The overshoot counts every sample from the step on (not only the "settled" ones the demo
figure takes, from 1 s after the step): the start must not overshoot at all by more than
5 %. The other targets (plateau error ≤ 2 %, ≥ 99 % of the settled time within ±10 %) are
asserted where the start reaches them within this 2 s hold: μ from 0.9 x up. Below, the
torque still approaches the request from below (no overshoot), more slowly than the hold
(at 0.6 x the first torque is 45 % of the request); the adaptation takes over at the next
step, and the demo's 0.9 x rated plateaus are beyond the pump's 40 bar there anyway.
"""

import math

import numpy as np
import pytest

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import reference_torque
from clutch_ros.model.adaptation import AdaptationSettings, scaled_params
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.offline.closed_loop import run_closed_loop
from clutch_ros.rig import RigPlant
from clutch_ros.rig.request_profile import demo_profile

W10 = 10 * 2 * math.pi / 60  # [rad/s]
SIGMA = AdaptationSettings().initial_std  # [1] the prior of the friction scale
GRID = (0.6, 0.8, 0.9, 1.0, 1.06, 1.1, 1.2, 1.3, 1.4)  # [1] truth μ / the preset's μ


@pytest.fixture(scope="module")
def setup():
    params = load_params(preset_path("flexiforce_8"))
    rated = float(reference_torque(params, 40e5, 35.0, W10))
    return params, rated, demo_profile(rated, quick=True)[:2]  # rest, then the first step


def _run(setup, ratio, settings=None):
    """Run the first step with the rig's μ at ``ratio`` x the estimator preset's."""
    params, rated, profile = setup
    rig = RigPlant.from_file("rig_truth", seed=0)
    truth = scaled_params(rig.truth, ratio * params.friction.mu_ref / rig.truth.friction.mu_ref)
    return run_closed_loop(params, RigPlant(truth, rig.params, seed=0), profile, settings,
                           adaptation=AdaptationSettings(), rated_torque=rated)


def _first_step(result, profile):
    """Return measured / request over every sample from the step on."""
    after = result.time >= profile[0].duration
    return result.measured[after] / result.request[after]


def test_grid_spans_two_sigma_of_the_prior():
    assert SIGMA == 0.2
    assert min(GRID) == pytest.approx(1 - 2 * SIGMA) and max(GRID) == pytest.approx(1 + 2 * SIGMA)


@pytest.mark.parametrize("ratio", GRID)
def test_first_step_never_overshoots_by_more_than_5_percent(setup, ratio):
    r = _run(setup, ratio)
    profile = setup[2]
    ratios = _first_step(r, profile)
    step = int(np.searchsorted(r.time, profile[0].duration))
    # nothing learned at the step: the prior's σ, the preset's μ
    assert r.friction_scale[step] == 1.0 and r.friction_scale_std[step] == SIGMA
    print(f"mu x {ratio}: first step max {ratios.max():.4f}, end {ratios[-100:].mean():.4f}, "
          f"within {r.within_10pct:.4f}, plateau error {r.steady_state_error:.4f}")
    assert ratios.max() <= 1.05
    assert r.worst_overshoot <= 1.05
    assert np.all((r.pressure_command >= 0.0) & (r.pressure_command <= 40e5))
    if ratio >= 0.9:
        assert r.steady_state_error <= 0.02
        assert r.within_10pct >= 0.99
    else:  # from below all the way, and closing: the last 0.1 s above where it began
        assert ratios[-100:].mean() > 0.9 and ratios[-100:].mean() > ratios[:500].max()


@pytest.mark.parametrize("ratio", (1.2, 1.4))
def test_without_the_start_margin_the_step_overshoots(setup, ratio):
    """The control: ``uncertainty_range`` 0 (only ``uncertainty_margin``'s 0.5 σ = +10 %)."""
    r = _run(setup, ratio, ControllerSettings(uncertainty_range=0.0))
    assert _first_step(r, setup[2]).max() > 1.05
