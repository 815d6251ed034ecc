"""Friction coefficient μ(T, p, ω) and the steady-state reference model (Eq. 1).

Units: lamella temperature T [°C], actuating pressure p [Pa], slip speed ω = ω_diff [rad/s],
torque [N m]. Every function takes scalars or arrays (numpy broadcasting) and returns a float
for all-scalar input, else an array.

Friction coefficient (thesis 2.1.1 and 6.2, Hypothesis 2)::

    μ = max(μ_min, μ_ref · f_T · f_p · f_ω)
    f_T = 1 + temperature_slope · (T − temperature_ref)            linear decay with T
    f_p = 1 − pressure_loss_at_ref · max(p, 0) / pressure_ref      0 % at 0 Pa, 5 % at 40 bar
    f_ω = 1 + (static_ratio − 1) · exp(−(ω / stribeck_speed)²)     Stribeck, static at ω = 0

Choices: the Stribeck transition is a Gaussian in ω (the classic exponential Stribeck curve with
exponent 2) so μ is smooth, even in ω and equals static_ratio·kinetic at zero slip; μ uses the
*actuating* pressure (the thesis's MISO model input), negative pressures count as 0; the floor
``mu_min`` keeps μ positive for extreme temperatures (it is the only non-smooth point).

Torque sign: a clutch never produces energy, so the transmitted torque has the sign of
ω_diff = ω_input − ω_output (it drives the slower shaft and brakes the faster one). The sign is
regularised as ``tanh(ω / sign_speed)`` with ``sign_speed`` ≤ ``stribeck_speed``/5 (default
0.02 rad/s ≈ 0.2 rpm), so T·ω ≥ 0 always and the torque is continuous through zero slip, where
it is 0. :func:`torque_capacity` gives the magnitude (what the pack can transmit at that
normal force, the value the inverse and the spline loads use).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "friction_coefficient",
    "slip_sign",
    "torque_capacity",
    "reference_torque",
    "mu_scalar",
]


def _out(value, *inputs):
    if all(np.ndim(v) == 0 for v in inputs):
        return float(value)
    return value


def friction_coefficient(params, lamella_temperature, actuating_pressure, slip_speed):
    """Return μ [-] at lamella temperature [°C], actuating pressure [Pa], slip speed [rad/s]."""
    fr = params.friction
    temp = np.asarray(lamella_temperature, dtype=float)
    press = np.asarray(actuating_pressure, dtype=float)
    omega = np.asarray(slip_speed, dtype=float)
    f_t = 1.0 + fr.temperature_slope * (temp - fr.temperature_ref)
    f_p = 1.0 - fr.pressure_loss_at_ref * np.maximum(press, 0.0) / fr.pressure_ref
    x = omega / fr.stribeck_speed
    f_w = 1.0 + (fr.static_ratio - 1.0) * np.exp(-(x * x))
    mu = np.maximum(fr.mu_ref * f_t * f_p * f_w, fr.mu_min)
    return _out(mu, lamella_temperature, actuating_pressure, slip_speed)


def mu_scalar(fr, lamella_temperature: float, actuating_pressure: float,
              slip_speed: float) -> float:
    """Scalar fast path of :func:`friction_coefficient` taking ``params.friction``."""
    f_t = 1.0 + fr.temperature_slope * (lamella_temperature - fr.temperature_ref)
    p = actuating_pressure if actuating_pressure > 0.0 else 0.0
    f_p = 1.0 - fr.pressure_loss_at_ref * p / fr.pressure_ref
    x = slip_speed / fr.stribeck_speed
    f_w = 1.0 + (fr.static_ratio - 1.0) * math.exp(-(x * x))
    mu = fr.mu_ref * f_t * f_p * f_w
    return mu if mu > fr.mu_min else fr.mu_min


def slip_sign(params, slip_speed):
    """Return the smooth torque sign tanh(ω / sign_speed) in [-1, 1] for ω [rad/s]."""
    return _out(np.tanh(np.asarray(slip_speed, dtype=float) / params.friction.sign_speed),
                slip_speed)


def torque_capacity(params, actuating_pressure, lamella_temperature, slip_speed):
    """Return |Eq. 1| = 2 R_e μ F_N N with F_N = max(p, 0)·A [N m] (no sign, ≥ 0)."""
    pk = params.pack
    press = np.maximum(np.asarray(actuating_pressure, dtype=float), 0.0)
    mu = friction_coefficient(params, lamella_temperature, press, slip_speed)
    cap = 2.0 * pk.effective_radius * pk.lamella_count * pk.piston_area * mu * press
    return _out(cap, actuating_pressure, lamella_temperature, slip_speed)


def reference_torque(params, actuating_pressure, lamella_temperature, slip_speed):
    """Return the steady-state reference torque of Eq. 1 [N m], signed like ω_diff.

    ``T = 2 · R_e · μ · F_N · N · tanh(ω / sign_speed)`` with ``F_N = max(p, 0) · A`` and μ
    from :func:`friction_coefficient` (see the module docstring for the sign convention).
    """
    cap = torque_capacity(params, actuating_pressure, lamella_temperature, slip_speed)
    sign = np.tanh(np.asarray(slip_speed, dtype=float) / params.friction.sign_speed)
    return _out(cap * sign, actuating_pressure, lamella_temperature, slip_speed)
