"""The simulated rig with a compliant drivetrain: the Test A preset (issue 24).

Thesis 3.1 (Test A, soft drive shafts): after a pressure increase the torque builds up
roughly in proportion to ω_diff, "a time delay of as much as 3-4 seconds was observed for the
lowest tested ω_diff". The ``rig_test_a`` preset takes that lowest ω_diff as 2 rpm (the thesis
does not state it). Build-up delay here: from the 40 bar request until the flange torque
first reaches 90 % of its settled value. Tolerance: the thesis's 3-4 s, i.e. 3.5 s ± 0.5 s.
"""

import numpy as np
import pytest

from clutch_ros.rig import RigPlant
from clutch_ros.rig.scenario import rpm_to_rad_s

DT = 1e-3  # [s] the rig's plant step
STEP_AT, SETTLE = 1.0, 9.0  # [s] pressure request at, then held for


def _build_up(rpm, preset="rig_test_a"):
    plant = RigPlant.from_file(preset, seed=1)
    plant.reset()
    w = rpm_to_rad_s(rpm)
    rows = []
    for k in range(1, int((STEP_AT + SETTLE) / DT) + 1):
        t = k * DT
        s = plant.step(DT, 40e5 if t > STEP_AT else 0.0, w)
        rows.append((t, s.true_torque, s.measured_torque, s.slip_speed, s.true_slip_speed))
    t, torque, measured, slip, clutch = map(np.array, zip(*rows))
    final = float(np.mean(torque[t > STEP_AT + SETTLE - 1.0]))
    delay = float(t[np.argmax(torque >= 0.9 * final)] - STEP_AT)
    return delay, final, t, torque, measured, slip, clutch


def test_test_a_delay_at_the_lowest_slip_speed():
    delay, final, t, torque, measured, slip, clutch = _build_up(2.0)
    assert 3.0 <= delay <= 4.0, delay
    assert final > 1000.0  # N m: the pack's capacity at 40 bar, reached in the end
    # while the torque builds up the clutch sticks; the motor's sensor still reads ω_m
    ramp = (t > STEP_AT + 0.5) & (t < STEP_AT + delay - 0.5)
    assert np.all(clutch[ramp] == 0.0)
    assert np.mean(slip[ramp]) == pytest.approx(rpm_to_rad_s(2.0), rel=0.02)
    rate = np.polyfit(t[ramp], torque[ramp], 1)[0]  # the torque rises at k ω_m
    assert rate == pytest.approx(1900.0 * rpm_to_rad_s(2.0), rel=0.02)
    assert np.all(np.abs(measured - torque) < 10.0)  # the flange measures it (noise only)


def test_delay_scales_with_one_over_the_slip_speed():
    slow = _build_up(2.0)[0]
    fast = _build_up(10.0)[0]
    assert fast < 0.3 * slow
    assert fast == pytest.approx(slow / 5.0, abs=0.25)  # plus the pump's own rise


def test_rigid_preset_runs_without_compliance():
    plant = RigPlant.from_file("rig_truth", seed=1)
    assert plant.drive is None
    a = _build_up(10.0, "rig_truth")
    assert a[0] < 0.5  # the stiff rig: the pump and pack time constants only


def test_golden_rig_is_elastic_with_the_thesis_delay():
    """The golden runs' plant (rig_truth made elastic, tests/data/golden) shows the delay too."""
    delay, final, *_ = _build_up(2.0, "rig_truth_elastic")
    assert 3.0 <= delay <= 4.0, delay
    assert final > 1000.0
