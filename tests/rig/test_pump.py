"""PumpModel: closed-form lag and rate limit, pressure limit, the kick, the pump current."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.pump import PumpModel, PumpParams

BAR = 1e5
DT = 1e-3


def run(pump, requests, dt=DT):
    out = np.array([pump.step(dt, r) for r in requests])
    return out[:, 0], out[:, 1]


def test_first_order_lag_closed_form_without_kick_and_slew():
    params = PumpParams(kick_gain=0.0, slew_rate=math.inf, time_constant=0.05)
    pump = PumpModel(params)
    p, _ = run(pump, [30 * BAR] * 500)
    t = DT * np.arange(1, 501)
    expected = 30 * BAR * (1.0 - np.exp(-t / 0.05))
    # zero-order-hold discretisation is exact for a step: only float round-off remains
    assert_allclose(p, expected, rtol=1e-12, atol=1e-6)


def test_rate_limit_alone_is_an_exact_ramp():
    params = PumpParams(kick_gain=0.0, time_constant=0.0, slew_rate=2e7)
    pump = PumpModel(params)
    p, _ = run(pump, [40 * BAR] * 400)
    t = DT * np.arange(1, 401)
    # 200 bar/s until 40 bar is reached at 0.2 s; exact up to round-off
    assert_allclose(p, np.minimum(2e7 * t, 40 * BAR), rtol=1e-12, atol=1e-3)


def test_lag_of_rate_limited_ramp_matches_continuous_closed_form():
    tau, slope = 0.05, 2e7
    pump = PumpModel(PumpParams(kick_gain=0.0, time_constant=tau, slew_rate=slope))
    p, _ = run(pump, [40 * BAR] * 200)  # the ramp lasts 0.2 s: stay on it
    t = DT * np.arange(1, 201)
    expected = slope * (t - tau * (1.0 - np.exp(-t / tau)))
    # the reference is a staircase reaching each ramp value at the step's start, so the
    # discrete response leads the continuous one by at most one step of the ramp
    assert_allclose(p, expected, atol=slope * DT)
    assert np.all(p >= expected - 1e-6)


def test_release_rate_limit_and_pressure_limits():
    pump = PumpModel(PumpParams(kick_gain=0.0, time_constant=0.0))
    p, _ = run(pump, [100 * BAR] * 500)
    assert p.max() == pytest.approx(60 * BAR)  # max_pressure clamps the request
    p, _ = run(pump, [0.0] * 200)
    # 400 bar/s release: 60 bar gone after 0.15 s
    assert_allclose(p[:149], 60 * BAR - 4e7 * DT * np.arange(1, 150), rtol=1e-12)
    assert p[-1] == 0.0
    pump.reset(20 * BAR)
    p, _ = run(pump, [math.nan, -5 * BAR] * 100)
    assert p[-1] == 0.0 and p.min() >= 0.0


def test_kick_overshoots_on_a_fast_step():
    pump = PumpModel()
    p, _ = run(pump, [40 * BAR] * 2000)
    peak = int(np.argmax(p))
    # documented shape: about +12 % near 0.36 s
    assert 1.08 * 40 * BAR < p[peak] < 1.16 * 40 * BAR
    assert 0.25 < peak * DT < 0.5
    # back within 2 % after 0.8 s and settled (0.1 %) after 1.5 s
    assert np.all(np.abs(p[800:] - 40 * BAR) < 0.02 * 40 * BAR)
    assert abs(p[1500] - 40 * BAR) < 1e-3 * 40 * BAR
    assert pump.kick < 1e2  # the pulse has decayed below 1 mbar


def test_no_kick_on_a_ramp_even_as_a_can_staircase():
    pump = PumpModel()
    t = DT * np.arange(4000)
    held = np.floor(t / 0.01) * 0.01  # requests arrive every 10 ms and are held
    request = np.interp(held, [0.0, 2.0, 4.0], [0.0, 40 * BAR, 0.0])
    kicks = []
    for r in request:
        pump.step(DT, r)
        kicks.append(pump.kick)
    assert max(kicks) == 0.0
    pump.reset()
    p, _ = run(pump, request)
    assert p.max() <= 40 * BAR


def _staircase_kick(rate: float) -> float:
    """Largest kick [Pa] of a ``rate`` [Pa/s] ramp to 25 bar sent as a 10 ms staircase.

    The pump of the demo's truth plant (the ``rig_truth`` preset).
    """
    from clutch_ros.rig import RigPlant

    pump = RigPlant.from_file("rig_truth", seed=0).pump
    t = DT * np.arange(1000)
    request = np.minimum(rate * np.floor(t / 0.01) * 0.01, 25 * BAR)
    kicks = []
    for r in request:
        pump.step(DT, r)
        kicks.append(pump.kick)
    return max(kicks)


def test_the_demo_rise_rate_is_below_the_kick_threshold_as_a_staircase():
    """The demo's 75 bar/s (PUMP_RISE) sends no kick; 90 bar/s kicks in the ripple.

    The ECU's 100 bar/s threshold applies to its smoothed request; a 10 ms staircase at
    90 bar/s steps 0.9 bar at once, and the smoothed rate right after each step is above
    100 bar/s although the mean is 90.
    """
    from clutch_ros.cli.demo import PUMP_RISE

    assert PUMP_RISE == 75 * BAR
    assert _staircase_kick(PUMP_RISE) == 0.0
    assert _staircase_kick(90 * BAR) > 1.0 * BAR  # 1.25 bar


def test_no_kick_on_release_and_smaller_kicks_on_small_steps():
    pump = PumpModel()
    pump.reset(40 * BAR)
    p, _ = run(pump, [0.0] * 1000)
    assert np.all(np.diff(p) <= 0.0) and pump.kick == 0.0
    overshoot = []
    for level in (10, 20, 30, 40):  # incremented steps of 10 bar
        p, _ = run(pump, [level * BAR] * 1500)
        overshoot.append(p.max() - level * BAR)
    assert all(0.3 * BAR < o < 2.0 * BAR for o in overshoot)
    pump.reset()
    p, _ = run(pump, [1.0 * BAR] * 1000)  # a 1 bar step is too small to kick
    assert p.max() <= 1.0 * BAR


def test_pump_current():
    params = PumpParams()
    pump = PumpModel(params)
    _, current = run(pump, [40 * BAR] * 3000)
    steady = params.current_idle + params.current_per_pressure * 40 * BAR
    assert current[-1] == pytest.approx(steady, rel=1e-6)  # 8.5 A
    assert current.max() > steady + 1.0  # building pressure costs flow
    assert current.max() <= params.current_max
    pump.reset()
    assert pump.current == pytest.approx(params.current_idle)


@pytest.mark.parametrize("kwargs", [
    {"time_constant": -1.0}, {"slew_rate": 0.0}, {"max_pressure": math.nan},
    {"kick_gain": -0.1}, {"kick_time_constant": 0.0}, {"current_max": math.inf},
])
def test_invalid_parameters_raise(kwargs):
    with pytest.raises(RigConfigError):
        PumpParams(**kwargs)


@pytest.mark.parametrize("dt", [0.0, -1e-3, math.nan, math.inf])
def test_invalid_dt_raises(dt):
    with pytest.raises(RigConfigError):
        PumpModel().step(dt, 1e5)
