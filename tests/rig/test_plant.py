"""RigPlant: truth steady torque, coulomb hysteresis, locked output, sensors, seeds."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model.pack import PackModel
from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.plant import RigPlant, RigPlantParams
from clutch_ros.rig.scenario import rpm_to_rad_s, table3_run
from clutch_ros.rig.simulator import run_offline
from clutch_ros.rig.thermal import ThermalParams

BAR = 1e5
DT = 1e-3
TEN_RPM = rpm_to_rad_s(10.0)


@pytest.fixture(scope="module")
def triangle():
    """Table 3 sequence 5 (24 s triangle, 0-40-0 bar) at 10 rpm, seed 0."""
    return run_offline(RigPlant(seed=0), table3_run(5, 10.0))


def test_held_40_bar_10_rpm_converges_to_truth_steady_torque():
    # hold the lamella temperature (huge heat capacity) so a steady state exists
    params = RigPlantParams(thermal=ThermalParams(lamella_heat_capacity=1e12))
    plant = RigPlant(params=params, seed=1)
    rows = [plant.step(DT, 40 * BAR, TEN_RPM) for _ in range(4000)]
    pressure = np.array([r.true_actuating_pressure for r in rows])
    measured = np.array([r.measured_torque for r in rows[-1000:]])
    # the truth: the pack model on rig_truth.yaml fed the same pressure, slip and temperature
    truth = load_params(preset_path("rig_truth"))
    pack = PackModel(truth)
    pack.reset()
    temperature = 35.0  # the plant steps the pack at the previous step's temperature
    for r, p in zip(rows, pressure):
        sample = pack.step(DT, p, r.true_slip_speed, temperature)
        temperature = r.true_lamella_temperature
    assert rows[-1].true_torque == pytest.approx(sample.torque, rel=1e-12)
    # steady: the last second is flat, and the noisy measurement averages to the truth
    # (noise 1.5 N m / sqrt(1000) ~ 0.05 N m; 0.3 N m is 6 sigma)
    tail = np.array([r.true_torque for r in rows[-1000:]])
    assert np.ptp(tail) < 0.5
    assert measured.mean() == pytest.approx(sample.torque, abs=0.3)
    assert np.std(measured - tail) == pytest.approx(1.5, rel=0.1)
    # the coulomb state sits within its few-% band around Eq. 1 with the truth's mu
    assert sample.torque == pytest.approx(sample.reference_torque, rel=0.08)
    # ... and the truth is not the estimator's preset (mu_ref +6 %)
    estimator = PackModel(load_params(preset_path("flexiforce_8")))
    estimator.reset(40 * BAR)
    ref = estimator.output(40 * BAR, TEN_RPM, 35.0).reference_torque
    assert sample.reference_torque > 1.04 * ref


def test_coulomb_truth_shows_hysteresis_on_24_s_triangle(triangle):
    t, p = triangle["time"], triangle["true_actuating_pressure"]
    torque, mu = triangle["true_torque"], triangle["mu"]
    up, down = (t > 1.0) & (t < 13.0), (t > 13.0) & (t < 25.0)
    for level in (10 * BAR, 20 * BAR, 30 * BAR):
        iu = np.flatnonzero(up)[np.argmin(np.abs(p[up] - level))]
        idn = np.flatnonzero(down)[np.argmin(np.abs(p[down] - level))]
        # rebound holds more torque than compression at the same pressure (Table 6) ...
        assert torque[idn] > 1.05 * torque[iu]
        # ... from normal force, not from mu (the pack got warmer: mu is lower on the way down)
        assert torque[idn] / mu[idn] > 1.05 * torque[iu] / mu[iu]
        # front loaded more than rear while compressing, less while releasing (Fig. 49)
        assert triangle["pressure_difference"][iu] > 0.0 > triangle["pressure_difference"][idn]


def test_locked_output_and_derived_wheel_speeds(triangle):
    assert np.all(triangle["output_speed"] == 0.0)
    assert_allclose(triangle["slip_speed"], triangle["input_speed"])
    running = (triangle["time"] > 0.5) & (triangle["time"] < 26.0)
    # speed noise 0.005 rad/s: 10 sigma
    assert_allclose(triangle["slip_speed"][running], TEN_RPM, atol=0.05)
    wheels = triangle["wheel_speeds"]
    assert_allclose(wheels[:, 0], triangle["input_speed"] / 3.0)
    assert_allclose(wheels[:, 1], wheels[:, 0])
    assert np.all(wheels[:, 2:] == 0.0)
    plant = RigPlant(params=RigPlantParams(axle_ratio=0.0))
    assert plant.step(DT, 0.0, 1.0).wheel_speeds.shape == (0,)


def test_flexiforce_front_sees_front_lamella_rear_sees_rear(triangle):
    plant = RigPlant(seed=0)  # same seed: same sensor gains and shares
    ff = plant.flexiforce
    for k in (3000, 9000, 12000, 20000):
        row = {key: triangle[key][k] for key in ("front_force", "rear_force",
                                                 "true_slip_speed", "normal_force")}
        assert row["front_force"] == row["normal_force"][-1]
        assert row["rear_force"] == row["normal_force"][0]
        clean = ff.voltages(row["front_force"], row["rear_force"], row["true_slip_speed"],
                            noise=False)
        # voltage noise is 8 mV (front) / 4 mV (rear): 6 sigma
        assert_allclose(triangle["ff_voltages"][k], clean, atol=0.05)
    assert triangle["ff_voltages"].max() < 6.0 and triangle["ff_voltages"].min() >= 0.0


def test_kick_and_heating_show_in_a_50_rpm_step():
    run = run_offline(RigPlant(seed=2), table3_run(1, 50.0))
    t = run["time"]
    p = run["true_actuating_pressure"]
    assert p.max() > 1.08 * 40 * BAR  # the kick (5.1.1)
    # the pack (c/k = 0.125 s) smooths the kick, but the front lamella still overshoots its
    # steady force shortly after the pressure peak, and the front sensors see it (5.1.1)
    force = run["front_force"]
    later = (t > 5.0) & (t < 6.0)
    k = np.argmax(force)
    assert 1.2 < t[k] < 2.5 and force[k] > 1.015 * force[later].mean()
    volts = run["ff_voltages"][:, :4].sum(axis=1)
    # 50 ms means: noise of the sum ~16 mV / sqrt(50)
    assert volts[k - 25:k + 25].mean() > volts[later].mean() + 0.05
    temp = run["true_lamella_temperature"]
    assert temp[0] == pytest.approx(35.0, abs=0.1)
    assert 60.0 < temp.max() < 130.0  # ~7 kW of slip power for 10 s
    torque = run["true_torque"]
    # hot lamellas transmit less (temperature_slope < 0): end of hold < start of hold
    assert torque[np.searchsorted(t, 10.5)] < torque[np.searchsorted(t, 2.5)]


def test_seed_reproduces_noise_and_sensors():
    a, b, c = RigPlant(seed=5), RigPlant(seed=5), RigPlant(seed=6)
    ra = [a.step(DT, 20 * BAR, 1.0) for _ in range(50)]
    rb = [b.step(DT, 20 * BAR, 1.0) for _ in range(50)]
    rc = [c.step(DT, 20 * BAR, 1.0) for _ in range(50)]
    assert [r.measured_torque for r in ra] == [r.measured_torque for r in rb]
    assert_allclose(ra[-1].ff_voltages, rb[-1].ff_voltages, rtol=0, atol=0)
    assert [r.measured_torque for r in ra] != [r.measured_torque for r in rc]
    assert [r.true_torque for r in ra] == [r.true_torque for r in rc]  # truth is noise-free
    gen = RigPlant(seed=np.random.default_rng(5))
    assert gen.step(DT, 0.0, 0.0).time == pytest.approx(DT)


def test_params_from_flat_and_errors():
    params = RigPlantParams.from_flat({
        "rig.pump.time_constant": 0.08, "rig.noise.torque": 0.0,
        "rig.motor_time_constant": 0.0, "clutch.lamella_count": 8,
    })
    assert params.pump.time_constant == 0.08 and params.noise.torque == 0.0
    assert params.motor_time_constant == 0.0
    with pytest.raises(RigConfigError):
        RigPlantParams.from_flat({"rig.pump.time_constnat": 0.08})
    with pytest.raises(RigConfigError):
        RigPlantParams.from_flat({"rig.noise.torque": -1.0})
    with pytest.raises(RigConfigError):
        RigPlant(seed="x")
    plant = RigPlant(params=params)
    r = plant.step(DT, 0.0, 2.0)
    assert r.slip_speed != 2.0 or r.true_slip_speed == 2.0  # ideal motor: command at once
    assert r.true_slip_speed == 2.0
    with pytest.raises(RigConfigError):
        plant.step(DT, 0.0, math.inf)
    with pytest.raises(RigConfigError):
        plant.step(0.0, 0.0, 0.0)


def test_from_file_reads_truth_and_rig_keys(tmp_path):
    text = preset_path("rig_truth").read_text()
    text += "    rig:\n      pump:\n        kick_gain: 0.0\n      noise:\n        torque: 0.0\n"
    path = tmp_path / "truth.yaml"
    path.write_text(text)
    plant = RigPlant.from_file(path, seed=3)
    assert plant.params.pump.kick_gain == 0.0 and plant.params.noise.torque == 0.0
    assert plant.truth.spline.law == "coulomb"
    r = plant.step(DT, 10 * BAR, 1.0)
    assert r.measured_torque == r.true_torque  # no torque noise
    assert RigPlant.from_file().params == RigPlantParams()
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("kick_gain", "kick_gian"))
    with pytest.raises(RigConfigError):
        RigPlant.from_file(bad)
