"""FlexiForce calibration (thesis §5.5, Eqs. 6-10) against the simulated sensors' known laws.

The rig's FlexiForceArray gives each sensor the exact law F = a_i v² + b_i v
(``truth_polynomials()``), so the fits have a known answer whenever their assumption holds:
"same force" when every sensor carries F/4 (no share imbalance), "same sensor" when all
sensors are alike (no gain variation).
"""

import numpy as np
import pytest

from clutch_ros.model.calibration import (
    CalibrationError,
    SensorCalibration,
    calibrate,
    calibrate_same_force,
    calibrate_same_sensor,
    compare_methods,
    quasi_static_mask,
)
from clutch_ros.rig.flexiforce import FlexiForceArray, FlexiForceParams

FORCES = np.linspace(0.0, 15000.0, 1501)  # [N] actuating force, 0..40 bar on 3.75e-3 m^2
AREA = 3.75e-3


def _voltages(array, forces=FORCES, noise=False, slip=0.0):
    return np.array([array.voltages(f, f, slip, noise=noise) for f in forces])


VOLTS = np.linspace(0.5, 4.0, 8)


def _curve(coefficients, volts=VOLTS):
    return coefficients[:, :1] * volts**2 + coefficients[:, 1:] * volts


@pytest.mark.parametrize("noise", [False, True])
def test_same_force_recovers_each_sensor_law(noise):
    array = FlexiForceArray(FlexiForceParams(share_imbalance=0.0, slip_redistribution=0.0),
                            rng=5)
    cal = calibrate_same_force(_voltages(array, noise=noise), FORCES)
    truth = array.truth_polynomials()
    # noise-free: exact; 8/4 mV noise: coefficients within 1 %, forces within 0.2 % of 3.75 kN
    tol = 1e-9 if not noise else 1e-2
    np.testing.assert_allclose(cal.coefficients, truth, rtol=tol)
    err = np.abs(_curve(cal.coefficients) - _curve(truth)).max()
    assert err <= (1e-9 if not noise else 2e-3) * 3750.0
    assert cal.method == "same_force" and cal.sensors_per_lamella == 4


@pytest.mark.parametrize("noise", [False, True])
def test_same_sensor_recovers_the_shared_law(noise):
    # identical sensors, unequal shares: Eq. 10's assumption
    array = FlexiForceArray(FlexiForceParams(gain_variation=0.0, slip_redistribution=0.0),
                            rng=6)
    cal = calibrate_same_sensor(_voltages(array, noise=noise), FORCES)
    nominal = np.tile([[250.0, 500.0]], (8, 1))
    np.testing.assert_allclose(array.truth_polynomials(), nominal)
    np.testing.assert_allclose(cal.coefficients, nominal, rtol=1e-9 if not noise else 5e-3)


def test_same_force_with_unequal_shares_gives_share_scaled_laws():
    # the general case: the per-sensor fit absorbs the share, a_fit = a_i / (4 s_i)
    array = FlexiForceArray(FlexiForceParams(slip_redistribution=0.0), rng=7)
    cal = calibrate_same_force(_voltages(array), FORCES)
    scaled = cal.coefficients * 4.0 * array.shares[:, None]
    np.testing.assert_allclose(scaled, array.truth_polynomials(), rtol=1e-9)
    front, rear = cal.lamella_forces(_voltages(array))
    np.testing.assert_allclose(front, FORCES, atol=1e-6)
    np.testing.assert_allclose(rear, FORCES, atol=1e-6)


def test_pressures_and_p_diff_from_voltages():
    array = FlexiForceArray(FlexiForceParams(slip_redistribution=0.0), rng=8)
    cal = calibrate_same_force(_voltages(array), FORCES)
    front = np.full(5, 12000.0)
    rear = np.array([12000.0, 11000.0, 10000.0, 9000.0, 8000.0])
    v = np.array([array.voltages(f, r, noise=False) for f, r in zip(front, rear)])
    est = cal.pressures(v, AREA)
    np.testing.assert_allclose(est.front, front / AREA, rtol=1e-9)
    np.testing.assert_allclose(est.rear, rear / AREA, rtol=1e-9)
    np.testing.assert_allclose(est.difference, (front - rear) / AREA, rtol=1e-9, atol=1e-6)


def test_methods_compared_on_a_rig_run():
    from clutch_ros.rig import RigPlant, run_offline, table3_run

    plant = RigPlant(seed=3)
    run = run_offline(plant, table3_run(2, 10.0))
    force = run["actuating_pressure"] * AREA
    mask = quasi_static_mask(run["time"], run["actuating_pressure"])
    comparison = compare_methods(run["ff_voltages"], force, AREA, mask)
    # the thesis found both methods to give similar pressures; so does the simulated rig
    assert comparison.difference_rms < 0.1e5  # < 0.1 bar
    assert comparison.pdiff_correlation > 0.99
    for cal in (comparison.same_force, comparison.same_sensor):
        est = cal.pressures(run["ff_voltages"], AREA)
        # P_diff dynamics follow the truth (the absolute level is the calibration's weakness)
        corr = np.corrcoef(est.difference, run["pressure_difference"])[0, 1]
        assert corr > 0.8, (cal.method, corr)
        assert cal.rmse[0] < 0.01 * force.max()  # front disc fits F_act within 1 % of range
    doc = comparison.to_dict()
    assert {"same_force", "same_sensor", "pdiff_rms_pa", "pdiff_correlation"} <= set(doc)
    again = SensorCalibration.from_dict(doc["same_sensor"])
    np.testing.assert_array_equal(again.coefficients, comparison.same_sensor.coefficients)
    assert "P_diff" in comparison.summary()


def test_quasi_static_mask_skips_transients():
    t = np.arange(0, 4000) * 1e-3
    p = np.where(t > 1.0, 40e5, 0.0) + np.where(t > 2.5, -20e5, 0.0)
    mask = quasi_static_mask(t, p, window=0.5)
    assert not mask[(t > 1.0) & (t < 1.5)].any()
    assert mask[(t > 1.6) & (t < 2.5)].all()
    assert not mask[(t > 2.5) & (t < 3.0)].any()
    assert mask[t > 3.1].all()
    assert not mask[t < 0.5].any()  # no full window yet


def test_refusals_name_the_problem():
    array = FlexiForceArray(FlexiForceParams(), rng=1)
    v = _voltages(array)
    dead = v.copy()
    dead[:, 1] = 0.0
    with pytest.raises(CalibrationError, match="front 2"):
        calibrate_same_force(dead, FORCES)
    with pytest.raises(CalibrationError, match="hardly varies"):
        calibrate_same_sensor(v, np.full(FORCES.shape, 15000.0))
    with pytest.raises(CalibrationError, match=r"\(n, 2k\)"):
        calibrate_same_force(v[:, :3], FORCES)
    with pytest.raises(CalibrationError, match="usable samples"):
        calibrate_same_force(v[:5], FORCES[:5])
    with pytest.raises(CalibrationError, match="unknown calibration method"):
        calibrate(v, FORCES, "same_everything")
    cal = calibrate(v, FORCES, "same_sensor")
    with pytest.raises(CalibrationError, match="8 sensors"):
        cal.sensor_forces(v[:, :4])
    with pytest.raises(CalibrationError, match="piston area"):
        cal.pressures(v, 0.0)
