"""Scenarios: Tables 3-4 schedules (DBP / PBD), closed loop, run_offline."""

import math

import numpy as np
import pytest

from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.plant import RigPlant
from clutch_ros.rig.scenario import (
    PiecewiseLinear,
    closed_loop_run,
    rpm_to_rad_s,
    table3_run,
    table4_run,
)
from clutch_ros.rig.simulator import run_offline

BAR = 1e5


def test_piecewise_linear_steps_are_left_continuous():
    f = PiecewiseLinear([0.0, 1.0, 1.0, 3.0], [0.0, 0.0, 2.0, 4.0])
    assert f(-1.0) == 0.0 and f(1.0) == 0.0 and f(1.0001) == pytest.approx(2.0001)
    assert f(2.0) == 3.0
    assert f(3.0) == 4.0 and f(10.0) == 4.0
    g = PiecewiseLinear.steps([(0.0, 5.0), (2.0, 1.0)], initial=9.0)
    assert g(0.001) == 5.0 and g(2.0) == 5.0 and g(2.001) == 1.0
    with pytest.raises(RigConfigError):
        PiecewiseLinear([1.0, 0.0], [0.0, 1.0])
    with pytest.raises(RigConfigError):
        PiecewiseLinear([0.0], [math.nan])


def test_table3_step_is_delta_before_pressure():
    sc = table3_run(1, 30.0)
    omega = rpm_to_rad_s(30.0)
    assert not sc.closed_loop and sc.initial_lamella_temperature == 35.0
    assert sc.duration == pytest.approx(1.0 + 10.0 + 3.0)
    assert sc.at(0.001).slip_speed == omega and sc.at(0.5).requested_pressure == 0.0
    assert sc.at(1.0).requested_pressure == 0.0  # a step is seen by the step after it
    assert sc.at(1.001).requested_pressure == 40 * BAR  # pressure after the slip
    assert sc.at(11.0).requested_pressure == 40 * BAR
    assert sc.at(11.001).requested_pressure == 0.0  # 10 s from request to 0 bar
    assert sc.at(14.0).slip_speed == omega  # slip held through the lead-out
    assert math.isnan(sc.at(3.0).torque_request)


def test_table3_incremented_steps_and_ramps():
    sc = table3_run(2, 10.0)
    levels = [sc.at(1.0 + t).requested_pressure / BAR for t in
              (0.1, 3.1, 6.1, 9.1, 14.9, 15.1, 18.1, 21.1, 24.1)]
    assert levels == [10, 20, 30, 40, 40, 30, 20, 10, 0]  # 8 steps in 24 s
    for seq, length in ((3, 4.0), (4, 12.0), (5, 24.0)):
        sc = table3_run(seq, 50.0)
        assert sc.at(1.0 + length / 2).requested_pressure == pytest.approx(40 * BAR)
        assert sc.at(1.0 + length / 4).requested_pressure == pytest.approx(20 * BAR)
        assert sc.at(1.0 + 3 * length / 4).requested_pressure == pytest.approx(20 * BAR)
        assert sc.at(1.0 + length).requested_pressure == 0.0
    with pytest.raises(RigConfigError):
        table3_run(6, 10.0)
    with pytest.raises(RigConfigError):
        table3_run(1, 0.0)


def test_table4_is_pressure_before_delta():
    sc = table4_run(4)
    omega = rpm_to_rad_s(30.0)
    assert sc.initial_lamella_temperature == 60.0
    assert sc.at(1.5).requested_pressure == 40 * BAR and sc.at(1.5).slip_speed == 0.0
    assert sc.at(2.5).slip_speed == omega  # positive slip step after the pressure
    assert sc.at(6.0).slip_speed == 0.0
    assert sc.at(7.0).slip_speed == -omega  # negative step
    assert sc.at(10.5).slip_speed == 0.0
    assert sc.at(11.0).requested_pressure == 40 * BAR and sc.at(11.01).requested_pressure == 0
    assert table4_run(1).at(5.0).slip_speed == rpm_to_rad_s(10.0)
    assert table4_run(1).initial_lamella_temperature == 35.0
    with pytest.raises(RigConfigError):
        table4_run(5)


@pytest.mark.parametrize("rpm", [10.0, 30.0, 50.0])
def test_schedules_equal_the_model_core_sequences(rpm):
    """The rig's scripted requests are the model core's Tables 3-4 series, sample by sample."""
    from clutch_ros.model import sequences

    cases = list(zip(range(1, 6), sequences.table3(rpm)))
    if rpm != 50.0:
        cases += [(s, seq) for s, seq in zip(range(1, 5), sequences.table4())
                  if seq.slip_rpm == rpm]
    for number, seq in cases:
        sc = table3_run(number, rpm) if seq.name != "pbd" else table4_run(number)
        assert sc.duration == pytest.approx(seq.t[-1])
        assert sc.initial_lamella_temperature == seq.lamella_temperature[0]
        points = [sc.at(t) for t in seq.t[1:]]  # sample k: the step ending at t[k]
        np.testing.assert_allclose([p.requested_pressure for p in points],
                                   seq.actuating_pressure[1:], rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose([p.slip_speed for p in points], seq.slip_speed[1:],
                                   rtol=1e-12)


def test_table4_run_starts_hot():
    run = run_offline(RigPlant(seed=0), table4_run(2), duration=0.5)
    assert run["true_lamella_temperature"][0] == pytest.approx(60.0, abs=0.01)
    assert run["true_oil_temperature"][0] == pytest.approx(35.0, abs=0.01)


def test_closed_loop_schedule_and_offline_run():
    sc = closed_loop_run((10.0, 30.0), segment=2.0, lead=0.5, rest=0.5,
                         torque_steps=[(0.5, 800.0), (2.5, 400.0)])
    assert sc.closed_loop and sc.duration == pytest.approx(5.0)
    assert math.isnan(sc.at(1.0).requested_pressure)
    assert sc.at(0.5).slip_speed == 0.0 and sc.at(1.0).slip_speed == rpm_to_rad_s(10.0)
    assert sc.at(3.0).slip_speed == rpm_to_rad_s(30.0) and sc.at(4.6).slip_speed == 0.0
    assert sc.at(1.0).torque_request == 800.0 and sc.at(3.0).torque_request == 400.0
    with pytest.raises(RigConfigError):
        run_offline(RigPlant(), sc)  # the pressure has to come from somewhere

    def source(t, last):
        return 30 * BAR if t >= 0.5 else 0.0

    run = run_offline(RigPlant(seed=3), sc, pressure_source=source)
    assert run["time"].shape == (5000,)
    assert run["requested_pressure"][-1] == 30 * BAR
    assert run["true_actuating_pressure"][-1] == pytest.approx(30 * BAR, rel=1e-3)
    assert np.all(run["torque_request"][1000:2400] == 800.0)
    rep = closed_loop_run((10.0,), segment=1.0, lead=0.5, rest=0.5, repeat=True)
    assert rep.at(2.7).slip_speed == rep.at(0.7).slip_speed == rpm_to_rad_s(10.0)
    assert rep.at(2.2).slip_speed == 0.0


def test_scenario_from_spec():
    from clutch_ros.rig.scenario import scenario_from_spec

    sc = scenario_from_spec("table3:5:10")
    assert sc.name == "table3_seq5_10rpm" and sc.at(13.0).requested_pressure == 40 * BAR
    assert scenario_from_spec("table4:2").initial_lamella_temperature == 60.0
    cl = scenario_from_spec("closed_loop:10,30,50:5", repeat=True)
    assert cl.closed_loop and cl.repeat and cl.duration == pytest.approx(1.0 + 15.0 + 1.0)
    assert cl.at(12.0).slip_speed == rpm_to_rad_s(50.0)
    assert scenario_from_spec("closed_loop").at(15.0).slip_speed == rpm_to_rad_s(30.0)
    assert scenario_from_spec("table3:1:30", repeat=True).repeat
    for bad in ("table3:9:10", "table3:1", "table5:1", "closed_loop:x", "", "table4:a"):
        with pytest.raises(RigConfigError):
            scenario_from_spec(bad)
