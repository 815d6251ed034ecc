"""The controller's adapted-model inversion and integral torque trim (model.control).

A static plant whose true torque is ``c`` times the model's (``T = c · C(p)``, the capacity
of Eq. 1) has a closed-form answer: the pressure with ``c · C(p) = T*``; the trim must find it
whatever ``c``, stay within its bounds and never push the pressure outside the limits.
"""

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.optimize import brentq

from clutch_ros.model.adaptation import scaled_params
from clutch_ros.model.control import TorqueController
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.model.inverse import capacity_scalar

W10 = 10 * 2 * math.pi / 60  # [rad/s]
TEMP = 40.0  # [°C]


def _static_loop(params, settings, request, c, ticks=400, measured=True, scale=1.0,
                 std=0.0, idle=0):
    """Run the controller on a static plant T = c C(p); return (controller, outputs).

    ``scale`` and ``std`` are the adapted friction scale and its standard deviation the
    estimate carries; the estimator's modelled torque is computed at scale 1. ``idle``
    ticks at a request of 0 N m come first (a rig at rest, measuring); outputs from the step.
    """
    ctl = TorqueController(params, settings)
    outs = []
    for k in range(-idle, ticks):
        t = k * settings.period
        ctl.set_request(t, request if k >= 0 else 0.0)
        ctl.set_model_scale(scale, 1.0, std)  # every tick, as the node does
        p = ctl.pressure
        model = capacity_scalar(params, p, TEMP, W10)  # the estimator at scale 1
        meas = c * model if measured else math.nan
        out = ctl.update(TEMP, W10, 0.0, meas, model, 1.0)
        if k >= 0:
            outs.append(out)
    return ctl, outs


@pytest.mark.parametrize("c", [0.9, 0.96, 1.0, 1.07, 1.12])
def test_trim_removes_a_constant_model_error(flexiforce, c):
    """Measured = c x model: the trim converges to the pressure the true plant needs."""
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9)
    request = 600.0
    ctl, outs = _static_loop(flexiforce, s, request, c)
    exact = brentq(lambda p: c * capacity_scalar(flexiforce, p, TEMP, W10) - request, 0, 50e5,
                   xtol=1e-6)
    # the trim integrates with a 0.2 s time constant: after 4 s it has converged to ~1e-8
    assert_allclose(ctl.pressure, exact, rtol=1e-6)
    assert_allclose(ctl.trim, (1.0 / c - 1.0), rtol=1e-5, atol=1e-9)
    assert_allclose(outs[-1].trim_pressure, ctl.pressure - capacity_inverse(flexiforce, request),
                    rtol=1e-5, atol=1e-3)


def capacity_inverse(params, torque):
    """Return p [Pa] with C(p) = torque at the test's operating point."""
    return brentq(lambda p: capacity_scalar(params, p, TEMP, W10) - torque, 0, 50e5, xtol=1e-6)


def test_trim_off_without_measurement(flexiforce):
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9)
    ctl, outs = _static_loop(flexiforce, s, 600.0, 1.1, measured=False)
    assert ctl.trim == 0.0 and all(o.trim_pressure == 0.0 for o in outs)
    assert_allclose(ctl.pressure, capacity_inverse(flexiforce, 600.0), rtol=1e-9)


def test_trim_released_when_the_measurement_drops_out(flexiforce):
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9)
    ctl, _ = _static_loop(flexiforce, s, 600.0, 1.1)
    held = ctl.trim
    assert held != 0.0
    ticks = round(s.trim_hold / s.period)
    for _ in range(ticks):  # a late frame or two: the trim holds
        out = ctl.update(TEMP, W10, 0.0, math.nan, 600.0)
        assert ctl.trim == held and out.trim_pressure != 0.0
    out = ctl.update(TEMP, W10, 0.0, math.nan, 600.0)  # longer: released
    assert ctl.trim == 0.0 and out.trim_pressure == 0.0


def test_adapted_scale_inverts_the_scaled_model(flexiforce):
    """With the right scale the feed-forward alone is exact: no trim needed."""
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9, trim_rate=0.0)
    ctl, _ = _static_loop(flexiforce, s, 800.0, 1.0, scale=1.15)
    scaled = scaled_params(flexiforce, 1.15)
    assert_allclose(capacity_scalar(scaled, ctl.pressure, TEMP, W10), 800.0, rtol=1e-8)


def test_scale_waits_for_a_request_change(flexiforce):
    """scale_hold: a new scale during a hold is taken at the next change of the request."""
    ctl = TorqueController(flexiforce, ControllerSettings(trim_rate=0.0))
    ctl.set_request(0.0, 500.0)
    ctl.update(TEMP, W10)
    ctl.set_request(0.01, 500.0)
    ctl.set_model_scale(1.2)
    ctl.update(TEMP, W10)
    assert ctl.friction_scale == 1.0
    ctl.set_request(0.02, 510.0)
    ctl.update(TEMP, W10)
    assert ctl.friction_scale == 1.2


def test_anti_windup_at_the_pressure_limit(flexiforce):
    """Unreachable torque (plant far weaker): the trim stops at its bound, pressure at max."""
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9, max_pressure=20e5)
    ctl, outs = _static_loop(flexiforce, s, 1000.0, 0.5)
    assert ctl.pressure == 20e5
    assert abs(ctl.trim) <= s.trim_limit
    assert all(o.pressure <= 20e5 for o in outs)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.floats(-100, 3000),
                          st.one_of(st.floats(-5000, 5000), st.just(math.nan),
                                    st.just(math.inf)),
                          st.floats(-5000, 5000), st.floats(0.3, 3.0)),
                min_size=1, max_size=80))
def test_pressure_never_outside_the_limits(flexiforce, rows):
    """Adversarial requests and torques: every command within [min, max], |trim| bounded."""
    s = ControllerSettings(min_pressure=2e5, max_pressure=30e5, trim_delay=0.0)
    ctl = TorqueController(flexiforce, s)
    for k, (request, meas, model, scale) in enumerate(rows):
        ctl.set_request(k * s.period, request)
        ctl.set_model_scale(scale)
        out = ctl.update(TEMP, W10, 0.0, meas, model, 1.0)
        assert s.min_pressure <= out.pressure <= s.max_pressure
        assert abs(ctl.trim) <= s.trim_limit
        assert math.isfinite(out.trim_pressure)


# --- caution while the friction scale is unlearned (uncertainty_margin) --------------------

FAST = {"rise_rate_limit": 1e9, "fall_rate_limit": 1e9}
# uncertainty_margin on its own: the start's range (uncertainty_range, test_control_start.py)
# would otherwise set the caution at the prior's σ
MARGIN = {"uncertainty_range": 0.0, **FAST}


def _exact(params, c, request):
    """Pressure [Pa] at which the plant T = c C(p) transmits ``request``."""
    return brentq(lambda p: c * capacity_scalar(params, p, TEMP, W10) - request, 0, 50e5,
                  xtol=1e-6)


def test_unlearned_mu_is_approached_from_below(flexiforce):
    """Rig μ +6 %, nothing learned (σ = the 0.2 prior): below the request until the trim acts.

    Torque is proportional to μ, so the inverse at s + 0.5 σ = 1.1 gives 1.06 / 1.1 of the
    request; the best estimate (margin 0) gives 1.06 of it: the first-step overshoot.
    """
    s = ControllerSettings(uncertainty_margin=0.5, **MARGIN)
    request, c = 600.0, 1.06
    ctl, outs = _static_loop(flexiforce, s, request, c, std=0.2, idle=5)
    delay = round(s.trim_delay / s.period)
    torques = [c * capacity_scalar(flexiforce, o.pressure, TEMP, W10) for o in outs]
    assert ctl.caution == pytest.approx(0.1) and ctl.friction_scale == pytest.approx(1.1)
    # once the target has ramped up, until the trim acts: below the request, not above
    assert_allclose(torques[delay // 2:delay], request * 1.06 / 1.1, rtol=1e-6)
    assert max(torques) <= request * (1 + 1e-6)  # from below all the way
    assert_allclose(ctl.pressure, _exact(flexiforce, c, request), rtol=1e-6)  # no offset
    _, bold = _static_loop(flexiforce, replace(s, uncertainty_margin=0.0), request, c,
                           std=0.2, idle=5)
    assert c * capacity_scalar(flexiforce, bold[delay - 1].pressure, TEMP, W10) \
        == pytest.approx(1.06 * request, rel=1e-6)


@pytest.mark.parametrize("c", [0.875, 0.95, 1.06, 1.17])
def test_caution_keeps_the_trims_reach(flexiforce, c):
    """The trim's bound is centred on the caution: same reach as without it.

    Every plant the trim reaches without caution (|1/c - 1| <= trim_limit) it still reaches
    with it, to the exact pressure.
    """
    s = ControllerSettings(uncertainty_margin=0.5, **MARGIN)
    ctl, _ = _static_loop(flexiforce, s, 600.0, c, std=0.2, ticks=600, idle=5)
    assert_allclose(ctl.pressure, _exact(flexiforce, c, 600.0), rtol=1e-6)
    assert_allclose(1.0 + ctl.trim, 1.1 / c, rtol=1e-5)


def test_no_caution_without_a_measurement(flexiforce):
    """Nothing would close the gap: the best estimate is inverted, no margin."""
    s = ControllerSettings(uncertainty_margin=0.5, **MARGIN)
    ctl, _ = _static_loop(flexiforce, s, 600.0, 1.06, measured=False, std=0.2, idle=5)
    assert ctl.caution == 0.0 and ctl.friction_scale == 1.0
    assert_allclose(ctl.pressure, capacity_inverse(flexiforce, 600.0), rtol=1e-9)
    off = ControllerSettings(uncertainty_margin=0.5, trim_rate=0.0, **MARGIN)
    ctl, _ = _static_loop(flexiforce, off, 600.0, 1.06, std=0.2, idle=5)  # trim off: none either
    assert ctl.caution == 0.0


def test_caution_dropped_when_the_measurement_drops_out(flexiforce):
    """A dropout releases the trim; the caution goes with it, mid-hold (no offset left)."""
    s = ControllerSettings(uncertainty_margin=0.5, **MARGIN)
    ctl, _ = _static_loop(flexiforce, s, 600.0, 1.06, std=0.2, idle=5)
    assert ctl.caution > 0.0
    for _ in range(round(s.trim_hold / s.period) + 1):
        ctl.update(TEMP, W10, 0.0, math.nan, 600.0)
    assert ctl.caution == 0.0 and ctl.friction_scale == 1.0 and ctl.trim == 0.0
    assert_allclose(ctl.pressure, capacity_inverse(flexiforce, 600.0), rtol=1e-9)


def test_caution_shrinks_with_the_std(flexiforce):
    """Learned (σ small): the margin is m σ, next to nothing; σ = 0 or margin 0: none."""
    for margin, std, expected in ((0.5, 0.004, 0.002), (0.5, 0.0, 0.0), (0.0, 0.2, 0.0),
                                  (1.0, math.nan, 0.0)):
        s = ControllerSettings(uncertainty_margin=margin, **MARGIN)
        ctl, _ = _static_loop(flexiforce, s, 600.0, 1.0, ticks=2, scale=1.05, std=std,
                                 idle=5)
        assert ctl.caution == pytest.approx(expected, abs=1e-12)
        assert ctl.friction_scale == pytest.approx(1.05 + expected)


def test_a_late_ramp_sample_is_no_step_but_a_fast_change_is(flexiforce):
    """A late ramp sample is no step; a change faster than ``lead_max_rate`` is.

    Published 0.15 s late, a ramp request moves by more than ``step_threshold`` but at the
    ramp's slope: the trim keeps integrating.
    """
    s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9)
    ctl, _ = _static_loop(flexiforce, s, 600.0, 1.1)
    held = ctl.trim
    assert held != 0.0 and s.step_threshold * 600.0 < 26.0  # 26 N m: more than the fraction
    t = 400 * s.period
    ctl.set_request(t + 0.15, 600.0 - 26.0, stamp=t + 0.15)  # 173 N m/s after a 0.15 s gap
    assert ctl.trim == held
    # delivered in a bunch, the stamps keep the spacing they were published with
    ctl.set_request(t + 0.151, 600.0 - 52.0, stamp=t + 0.30)
    assert ctl.trim == held
    # the control: the same 26 N m as the next 20 ms sample is 1300 N m/s, a step
    ctl.set_request(t + 0.171, 600.0 - 78.0, stamp=t + 0.32)
    assert ctl.trim == 0.0


def test_trim_holds_through_a_late_transient_then_acts(flexiforce):
    """After ``trim_delay`` the trim still holds while the measurement is beyond its reach.

    The plant's torque arrives late (a pressure path slow: measured 0 until 0.3 s after
    ``trim_delay``, then the true c = 1.05 x model): the trim must not integrate the missing torque,
    and once the measurement is in reach it converges as before. The control with
    ``trim_settle_time`` 0 winds up to its bound.
    """
    def run(settle):
        s = ControllerSettings(rise_rate_limit=1e9, fall_rate_limit=1e9,
                               trim_settle_time=settle, uncertainty_margin=0.0)
        ctl = TorqueController(flexiforce, s)
        late = s.trim_delay + 0.3  # [s] the torque arrives
        peak = 0.0
        for k in range(300):
            t = k * s.period
            ctl.set_request(t, 600.0)
            model = capacity_scalar(flexiforce, ctl.pressure, TEMP, W10)
            meas = 0.0 if t < late else 1.05 * model
            ctl.update(TEMP, W10, 0.0, meas, model, 1.0)
            if t < late:
                peak = max(peak, abs(ctl.trim))
        return ctl, peak

    held, peak = run(ControllerSettings.trim_settle_time)
    assert peak == 0.0  # the missing torque was never integrated
    assert_allclose(held.trim, 1.0 / 1.05 - 1.0, rtol=1e-4)  # then it converged
    wound, peak = run(0.0)
    assert_allclose(peak, ControllerSettings.trim_limit, rtol=1e-9)  # the control: at its bound
