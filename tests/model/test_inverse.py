"""Inverse model: inverse(forward(p)) = p, closed form, unreachable and bad requests."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    InputError,
    UnreachableTorqueError,
    pressure_for_torque,
    pressure_for_torque_array,
    solve_pressure,
    torque_capacity,
)


@pytest.mark.parametrize("temp, slip", [(35.0, 1.047), (80.0, 3.14), (150.0, 0.0),
                                        (20.0, -5.0)])
def test_inverse_of_forward_over_the_whole_range(flexiforce, temp, slip):
    pressures = np.linspace(0.0, flexiforce.pack.max_pressure, 201)
    torques = torque_capacity(flexiforce, pressures, temp, slip)
    back = pressure_for_torque_array(flexiforce, torques, temp, slip)
    # brentq with xtol 1e-9 Pa, rtol 4 eps: exact to ~1e-15 relative, 1e-9 Pa absolute
    assert_allclose(back, pressures, rtol=1e-12, atol=1e-8)


def test_closed_form_quadratic(flexiforce):
    # above the mu floor C(p) = c p (1 - l p / p_ref): solve the quadratic independently
    fr, pk = flexiforce.friction, flexiforce.pack
    temp, slip, torque = 60.0, 2.0, 900.0
    mu0 = fr.mu_ref * (1 + fr.temperature_slope * (temp - fr.temperature_ref)) * (
        1 + (fr.static_ratio - 1) * math.exp(-(slip / fr.stribeck_speed) ** 2))
    c = 2 * pk.effective_radius * pk.lamella_count * pk.piston_area * mu0
    a = c * fr.pressure_loss_at_ref / fr.pressure_ref
    p = (c - math.sqrt(c * c - 4 * a * torque)) / (2 * a)  # the root below the maximum
    assert_allclose(pressure_for_torque(flexiforce, torque, temp, slip), p, rtol=1e-12)


def test_zero_negative_and_non_finite_requests(flexiforce):
    assert pressure_for_torque(flexiforce, 0.0, 35.0, 1.0) == 0.0
    assert pressure_for_torque(flexiforce, 0.0, 35.0, 1.0, spline_correction=2e5) == 0.0
    with pytest.raises(InputError, match=">= 0"):
        pressure_for_torque(flexiforce, -10.0, 35.0, 1.0)
    for bad in ((math.nan, 35.0, 1.0), (100.0, math.inf, 1.0), (100.0, 35.0, math.nan)):
        with pytest.raises(InputError):
            pressure_for_torque(flexiforce, *bad)


def test_unreachable_clamps_or_raises(flexiforce):
    p_max = flexiforce.pack.max_pressure
    cap = torque_capacity(flexiforce, p_max, 35.0, 1.0)
    sol = solve_pressure(flexiforce, cap * 1.2, 35.0, 1.0)
    assert sol.pressure == p_max and sol.limited and "unreachable" in sol.reason
    assert_allclose(sol.predicted_torque, cap, rtol=1e-15)
    with pytest.raises(UnreachableTorqueError, match="exceeds"):
        pressure_for_torque(flexiforce, cap * 1.2, 35.0, 1.0, clamp=False)
    # exactly reachable at the bound: no clamp
    assert_allclose(pressure_for_torque(flexiforce, cap, 35.0, 1.0, clamp=False), p_max,
                    rtol=1e-12)


def test_spline_correction_added_and_clamped(flexiforce):
    base = solve_pressure(flexiforce, 800.0, 35.0, 1.0)
    corr = solve_pressure(flexiforce, 800.0, 35.0, 1.0, spline_correction=1.5e5)
    assert corr.pressure == base.pressure + 1.5e5 and not corr.limited
    assert corr.steady_state_pressure == base.steady_state_pressure
    low = solve_pressure(flexiforce, 10.0, 35.0, 1.0, spline_correction=-5e5)
    assert low.pressure == 0.0 and low.limited and "0 Pa" in low.reason
    high = solve_pressure(flexiforce, 1200.0, 35.0, 1.0, spline_correction=40e5)
    assert high.pressure == flexiforce.pack.max_pressure and high.limited


def test_zero_slip_uses_static_friction(flexiforce):
    # at zero slip the capacity is the static one: less pressure for the same torque
    assert (pressure_for_torque(flexiforce, 1000.0, 35.0, 0.0)
            < pressure_for_torque(flexiforce, 1000.0, 35.0, 5.0))


def test_solution_equals_brentqs_root_where_mu_is_linear_or_floored(flexiforce):
    # the closed form (mu above its floor) and the brentq fallback (floor reached) both
    # agree with a brentq root of the forward capacity to rounding
    from scipy.optimize import brentq

    fr, p_max = flexiforce.friction, flexiforce.pack.max_pressure
    floored = fr.temperature_ref + (fr.mu_min / fr.mu_ref - 1.0) / fr.temperature_slope
    rng = np.random.default_rng(7)
    for temp in [*rng.uniform(-20.0, 150.0, 30), floored + 5.0 * np.sign(-fr.temperature_slope)]:
        slip = float(rng.uniform(-20.0, 20.0))
        cap = float(torque_capacity(flexiforce, p_max, temp, slip))
        torque = float(rng.uniform(0.01, 1.0)) * cap
        root = brentq(lambda p, t=temp, w=slip, q=torque: float(
            torque_capacity(flexiforce, p, t, w)) - q, 0.0, p_max, xtol=1e-9,
            rtol=4 * np.finfo(float).eps)
        assert_allclose(pressure_for_torque(flexiforce, torque, temp, slip), root,
                        rtol=1e-12, atol=1e-8)
