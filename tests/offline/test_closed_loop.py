"""The controller on the simulated rig, offline: the ±10 % claim without timing noise."""

import math

import numpy as np
import pytest

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import reference_torque
from clutch_ros.model.control import TorqueController, command_pressure
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.offline.closed_loop import run_closed_loop
from clutch_ros.rig import RigPlant
from clutch_ros.rig.request_profile import demo_profile

W10 = 10 * 2 * math.pi / 60  # [rad/s] 10 rpm


@pytest.fixture(scope="module")
def params():
    return load_params(preset_path("flexiforce_8"))


@pytest.fixture(scope="module")
def profile(params):
    rated = float(reference_torque(params, 40e5, 35.0, W10))
    return demo_profile(rated, quick=True)


def test_default_controller_holds_the_band_on_the_mismatched_truth(params, profile):
    plant = RigPlant.from_file("rig_truth", seed=0)
    assert plant.truth.spline.law == "coulomb" and params.spline.law != "coulomb"
    r = run_closed_loop(params, plant, profile)
    assert r.within_10pct >= 0.95, r.within_10pct
    assert r.longest_overshoot_s <= 0.5
    assert np.all(r.pressure_command >= 0.0) and np.all(r.pressure_command <= 40e5)


def test_lead_and_correction_each_matter(params, profile):
    # The claims in the controller's docstring: both parts earn their place.
    base = ControllerSettings()
    full = run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile, base)
    no_lead = run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile,
                              ControllerSettings(lead_time=0.0, fall_lead_time=0.0))
    no_corr = run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile,
                              ControllerSettings(correction_gain=0.0))
    assert no_lead.within_10pct < full.within_10pct - 0.1
    assert no_corr.within_10pct < full.within_10pct - 0.05


def test_overshoot_guard_caps_pressure(params):
    request = 600.0
    guard = command_pressure(params, 1.05 * request, 40.0, W10, correction_gain=0.0)
    # A huge positive correction would ask for much more; the guard holds it at the
    # steady-state inverse of (1 + margin) x request.
    cmd = command_pressure(params, request, 40.0, W10, spline_correction=20e5,
                           overshoot_margin=0.05)
    assert "overshoot guard" in cmd.reasons
    np.testing.assert_allclose(cmd.pressure, guard.steady_state_pressure, rtol=1e-9)  # same solve


@pytest.mark.parametrize("bad", [math.nan, -5.0, math.inf])
def test_any_request_gives_a_command_within_limits(params, bad):
    ctl = TorqueController(params, ControllerSettings(max_pressure=30e5))
    assert ctl.set_request(0.0, bad)  # a warning names the bad value
    for _ in range(50):
        out = ctl.update(40.0, W10, 0.0)
        assert 0.0 <= out.pressure <= 30e5 and math.isfinite(out.pressure)
    ctl.set_request(1.0, 1e9)  # far beyond the clutch's capacity
    for _ in range(200):
        out = ctl.update(40.0, W10, 1e9)
        assert 0.0 <= out.pressure <= 30e5
    assert out.limited and out.reason


def test_rise_rate_limit_and_immediate_fail_safe(params):
    s = ControllerSettings(period=0.01, rise_rate_limit=90e5)
    ctl = TorqueController(params, s)
    ctl.set_request(0.0, 1000.0)
    pressures = [ctl.update(40.0, W10, 0.0).pressure for _ in range(100)]
    steps = np.diff([0.0, *pressures])
    assert steps.max() <= 90e5 * 0.01 * (1 + 1e-12)  # exact by construction
    assert pressures[-1] > 20e5
    out = ctl.fail_safe("stale estimate")
    assert out.pressure == 0.0 and "stale estimate" in out.reason


def test_command_delay_reaches_the_pump_that_much_later(params, profile):
    """``command_delay``: the pump starts building pressure that much after the first command."""
    first = {}
    for delay in (0.0, 0.08):
        r = run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile[:2],
                            command_delay=delay)
        k = np.argmax(r.pressure_command > 0.0)
        # 0.5 bar: well above the pressure sensor's noise at 0 bar
        building = k + np.argmax(r.actuating_pressure[k:] > 0.5e5)
        first[delay] = r.time[building] - r.time[k]
    # rounded to 1 ms plant steps (the only tolerance; the plant is deterministic)
    np.testing.assert_allclose(first[0.08] - first[0.0], 0.08, atol=1.5e-3)
    with pytest.raises(ValueError, match="command_delay"):
        run_closed_loop(params, RigPlant.from_file("rig_truth", seed=0), profile[:2],
                        command_delay=-0.01)


def test_fall_lead_time_leads_falling_requests_only(params):
    """The lead on a falling request is ``fall_lead_time`` x slope; rising uses ``lead_time``."""
    def run(settings, start, end):
        ctl = TorqueController(params, settings)
        n = 40  # 0.4 s of a 250 N m/s ramp at the 100 Hz control period
        for k in range(n):
            t = k * settings.period
            ctl.set_request(t, start + (end - start) * k / n)
            out = ctl.update(40.0, W10)
        return ctl, out

    short = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9, fall_lead_time=0.2)
    long_ = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9, fall_lead_time=0.4)
    (a, down_short), (b, down_long) = run(short, 700.0, 600.0), run(long_, 700.0, 600.0)
    slope = a.request_slope()
    assert slope < 0.0
    # the lead's torque: 0.2 s more of a -250 N m/s slope -> -50 N m; compare the pressures
    # the steady-state inverse gives for the two targets (same solve, 1e-9 relative)
    expected_short = command_pressure(params, a.target + 0.2 * slope, 40.0, W10)
    expected_long = command_pressure(params, b.target + 0.4 * slope, 40.0, W10)
    np.testing.assert_allclose(down_short.pressure, expected_short.pressure, rtol=1e-9)
    np.testing.assert_allclose(down_long.pressure, expected_long.pressure, rtol=1e-9)
    assert down_long.pressure < down_short.pressure
    # rising: fall_lead_time plays no part (same bits)
    assert run(short, 600.0, 700.0)[1].pressure == run(long_, 600.0, 700.0)[1].pressure
