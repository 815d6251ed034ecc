"""Friction coefficient mu(T, p, w), the torque sign convention and Eq. 1."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import friction_coefficient, reference_torque, slip_sign, torque_capacity
from clutch_ros.model.friction import mu_scalar


def closed_form_mu(fr, temp, p, w):
    """Section 6.2 / 2.1.1 written out independently of the module."""
    f_t = 1.0 + fr.temperature_slope * (temp - fr.temperature_ref)
    f_p = 1.0 - fr.pressure_loss_at_ref * max(p, 0.0) / fr.pressure_ref
    f_w = 1.0 + (fr.static_ratio - 1.0) * math.exp(-((w / fr.stribeck_speed) ** 2))
    return max(fr.mu_min, fr.mu_ref * f_t * f_p * f_w)


@pytest.mark.parametrize("temp, p, w", [(35.0, 0.0, 1.0), (35.0, 40e5, 1.047), (80.0, 20e5, 0.3),
                                         (150.0, 40e5, -3.14), (35.0, -1e5, 0.0)])
def test_closed_form(flexiforce, temp, p, w):
    fr = flexiforce.friction
    # same formula, different code: agree to rounding
    assert_allclose(friction_coefficient(flexiforce, temp, p, w),
                    closed_form_mu(fr, temp, p, w), rtol=1e-14)
    assert_allclose(mu_scalar(fr, temp, p, w), closed_form_mu(fr, temp, p, w), rtol=1e-14)


def test_pressure_loss_zero_at_zero_and_five_percent_at_40_bar(flexiforce):
    far = 100.0  # rad/s: the Stribeck term is exp(-40000) = 0, so mu is purely kinetic
    mu0 = friction_coefficient(flexiforce, 35.0, 0.0, far)
    mu40 = friction_coefficient(flexiforce, 35.0, 40e5, far)
    assert_allclose(mu0, flexiforce.friction.mu_ref, rtol=1e-15)  # exact: all factors are 1
    assert_allclose(mu40 / mu0, 0.95, rtol=1e-14)  # thesis 6.2: 5 % at 40 bar
    # linear in between, and negative gauge pressure counts as 0
    assert_allclose(friction_coefficient(flexiforce, 35.0, 20e5, far) / mu0, 0.975, rtol=1e-14)
    assert friction_coefficient(flexiforce, 35.0, -5e5, far) == mu0


def test_linear_temperature_decay_and_floor(flexiforce):
    temps = np.array([35.0, 60.0, 100.0, 150.0])
    mu = friction_coefficient(flexiforce, temps, 0.0, 100.0)
    assert_allclose(np.diff(mu) / np.diff(temps),
                    flexiforce.friction.mu_ref * flexiforce.friction.temperature_slope,
                    rtol=1e-9)  # constant slope = linear (differences of O(1e-3) values)
    hot = friction_coefficient(flexiforce, 5000.0, 0.0, 100.0)
    assert hot == flexiforce.friction.mu_min > 0.0


def test_static_coefficient_at_zero_slip_and_stribeck_transition(flexiforce):
    fr = flexiforce.friction
    mu_static = friction_coefficient(flexiforce, 35.0, 0.0, 0.0)
    assert_allclose(mu_static, fr.static_ratio * fr.mu_ref, rtol=1e-15)
    # one Stribeck speed away, (ratio - 1) has decayed by e^-1
    mu_s = friction_coefficient(flexiforce, 35.0, 0.0, fr.stribeck_speed)
    assert_allclose((mu_s / fr.mu_ref - 1.0) / (fr.static_ratio - 1.0), math.exp(-1.0),
                    rtol=1e-12)


def test_mu_continuous_and_even_through_zero_slip(flexiforce):
    w = np.linspace(-1e-3, 1e-3, 2001)  # straddles 0 with a sample exactly at 0
    mu = friction_coefficient(flexiforce, 35.0, 40e5, w)
    assert_allclose(mu, mu[::-1], rtol=1e-15)  # even in w (same |w| bit for bit)
    # continuity: no jump between neighbours beyond the Lipschitz bound of the Gaussian
    # (max slope of (r-1) exp(-x^2) is (r-1) sqrt(2/e) / w_s)
    fr = flexiforce.friction
    lipschitz = fr.mu_ref * (fr.static_ratio - 1.0) * math.sqrt(2 / math.e) / fr.stribeck_speed
    assert np.max(np.abs(np.diff(mu))) <= lipschitz * 1e-6 * 1.0001
    # and the one-sided limits at 0 equal the value at 0
    at0 = friction_coefficient(flexiforce, 35.0, 40e5, 0.0)
    assert_allclose([mu[999], mu[1001]], at0, rtol=1e-11)  # |w| = 1e-6: change ~ 1e-12


def test_sign_convention_no_energy_generated(flexiforce):
    half = np.linspace(0.0, 5.0, 5001)
    w = np.concatenate([-half[::-1], half[1:]])  # exactly symmetric about 0
    torque = reference_torque(flexiforce, 40e5, 35.0, w)
    assert np.all(torque * w >= 0.0)  # a clutch never produces energy
    assert_allclose(torque, -torque[::-1], rtol=0, atol=0)  # odd in w, bit for bit
    assert reference_torque(flexiforce, 40e5, 35.0, 0.0) == 0.0
    # the sign saturates within a few sign_speed, far inside the Stribeck transition
    ws = flexiforce.friction.sign_speed
    assert slip_sign(flexiforce, 10 * ws) > 0.999999
    assert 10 * ws < flexiforce.friction.stribeck_speed


def test_eq1_closed_form(flexiforce):
    pk = flexiforce.pack
    p, temp, w = 30e5, 50.0, 3.0
    mu = friction_coefficient(flexiforce, temp, p, w)
    expected = 2 * pk.effective_radius * mu * (p * pk.piston_area) * pk.lamella_count
    assert_allclose(torque_capacity(flexiforce, p, temp, w), expected, rtol=1e-15)
    assert_allclose(reference_torque(flexiforce, p, temp, w), expected * math.tanh(w / 0.02),
                    rtol=1e-15)
    assert torque_capacity(flexiforce, -1e5, temp, w) == 0.0


def test_vectorised_shapes(flexiforce):
    out = friction_coefficient(flexiforce, np.full((3, 1), 35.0), np.array([0.0, 1e6]), 1.0)
    assert out.shape == (3, 2)
    assert isinstance(friction_coefficient(flexiforce, 35.0, 1e6, 1.0), float)
