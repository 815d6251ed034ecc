"""FlexiForceArray: monotonic concave response, 0..6 V, bounded variation, reproducible."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.flexiforce import FlexiForceArray, FlexiForceParams

PISTON_AREA = 3.75e-3  # [m^2]: 40 bar -> 15 kN


def sweep(array, forces):
    return np.array([array.voltages(f, f, noise=False) for f in forces])


def test_monotonic_and_concave():
    array = FlexiForceArray(rng=1)
    forces = np.linspace(0.0, 20000.0, 401)
    v = sweep(array, forces)
    assert_allclose(v[0], 0.0)
    assert np.all(np.diff(v, axis=0) >= 0.0)
    unclipped = v[:, :].max(axis=1) < array.params.output_max
    d2 = np.diff(v[unclipped], n=2, axis=0)
    assert np.all(d2 <= 1e-12)  # concave


def test_voltages_within_op_amp_range_and_well_below_6v_at_40_bar():
    array = FlexiForceArray(rng=2)
    for force in (0.0, 1e3, 1e5, -500.0):
        v = array.voltages(force, force)
        assert np.all(v >= 0.0) and np.all(v <= array.params.output_max) and v.max() < 6.0
    v = array.voltages(40e5 * PISTON_AREA, 40e5 * PISTON_AREA, noise=False)
    assert 1.0 < v.min() and v.max() < 5.5


def test_sensor_to_sensor_variation_bounded_by_40_percent():
    gains = []
    for seed in range(50):
        array = FlexiForceArray(rng=seed)
        forces = np.full(8, 3000.0)
        ratio = array.clean_voltages(forces) / array.params.nominal_voltage(forces)
        assert np.all(ratio >= 0.6) and np.all(ratio <= 1.4)
        assert_allclose(ratio, array.gains)
        gains.extend(array.gains)
    # the draws use the whole +-40 % band
    assert min(gains) < 0.65 and max(gains) > 1.35
    assert np.all(FlexiForceArray(FlexiForceParams(gain_variation=0.0)).gains == 1.0)


def test_reproducible_with_a_seed():
    a, b, c = FlexiForceArray(rng=7), FlexiForceArray(rng=7), FlexiForceArray(rng=8)
    va = [a.voltages(f, 0.9 * f, slip_speed=1.0) for f in (1e3, 5e3, 1e4)]
    vb = [b.voltages(f, 0.9 * f, slip_speed=1.0) for f in (1e3, 5e3, 1e4)]
    vc = [c.voltages(f, 0.9 * f, slip_speed=1.0) for f in (1e3, 5e3, 1e4)]
    assert_allclose(va, vb, rtol=0, atol=0)
    assert not np.allclose(va, vc)
    gen = np.random.default_rng(7)
    assert_allclose(FlexiForceArray(rng=gen).gains, a.gains)


def test_force_split_and_truth_polynomials():
    array = FlexiForceArray(rng=3)
    shares = array.shares
    assert_allclose([shares[:4].sum(), shares[4:].sum()], 1.0)
    assert np.all(np.abs(shares * 4 - 1.0) < 0.15 / 0.85 + 1e-9)
    forces = array.sensor_forces(12000.0, 9000.0, slip_speed=3.0)
    assert_allclose([forces[:4].sum(), forces[4:].sum()], [12000.0, 9000.0])
    still = array.sensor_forces(12000.0, 9000.0)
    assert forces[1] < still[1] and forces[3] > still[3]  # R2 drops, R4 rises (5.2)
    # each sensor's exact law F = a v^2 + b v inverts its clean voltage
    v = array.clean_voltages(still)
    poly = array.truth_polynomials()
    assert_allclose(poly[:, 0] * v**2 + poly[:, 1] * v, still, rtol=1e-9)


def test_noise_front_noisier_than_rear():
    array = FlexiForceArray(rng=4)
    clean = array.voltages(10000.0, 10000.0, noise=False)
    noisy = np.array([array.voltages(10000.0, 10000.0) for _ in range(4000)]) - clean
    std = noisy.std(axis=0)
    assert_allclose(std[:4], 0.008, rtol=0.1)
    assert_allclose(std[4:], 0.004, rtol=0.1)


@pytest.mark.parametrize("kwargs", [
    {"gain_variation": 1.0}, {"share_imbalance": -0.1}, {"poly_a": 0.0},
    {"output_max": 0.0}, {"noise_std_front": -1.0},
])
def test_invalid_parameters_raise(kwargs):
    with pytest.raises(RigConfigError):
        FlexiForceParams(**kwargs)
    with pytest.raises(RigConfigError):
        FlexiForceArray(rng="seed")
