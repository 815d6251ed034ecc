"""Torque-to-pressure control law: model inverse, spline-friction correction, overshoot guard.

Pure functions used by the controller node (and testable without ROS). Units: torque [N m],
pressure [Pa], temperature [°C], slip speed [rad/s].

The law, for a torque target ``T*``:

1. steady-state inverse ``p_ss = inverse(T*)`` (Eq. 1 with the friction coefficient's
   pressure dependence, :func:`clutch_ros.model.pressure_for_torque`);
2. dynamic spline-friction correction: the estimator reports, at the current actuating
   pressure ``p``, what the pack transmits (``T_model``, Eq. 27 with the spline-friction state)
   and what the steady-state model would give (``T_ref``, Eq. 1). Their difference is torque
   the pack currently loses (compression: ``T_model < T_ref``) or holds on to (rebound:
   ``T_model > T_ref``). It is converted to pressure with the local slope ``dT_ref/dp`` and
   added, scaled by ``correction_gain``. Choice: the correction uses the state at the *current*
   pressure rather than re-simulating the pack at ``p_ss``, because the spline-friction state
   changes slowly compared with the control period and this keeps the law O(1) per tick;
3. overshoot guard: the pressure never exceeds ``inverse((1 + margin) * guard_torque)``, since
   overshoot is the worse failure (thesis §1.2);
4. a request of 0 N m (or below) commands 0 Pa.

Limits and rate limits on the pressure are the caller's (node parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clutch_ros.model.errors import ModelError

__all__ = ["ControlCommand", "command_pressure"]

_MIN_SLOPE_PRESSURE = 1e4  # [Pa] below this the slope dT/dp is taken at this pressure


@dataclass(frozen=True)
class ControlCommand:
    """Result of one control-law evaluation.

    Attributes:
        pressure: commanded actuating pressure before node limits [Pa]
        steady_state_pressure: the steady-state inverse of the target [Pa]
        correction: spline-friction correction added [Pa]
        predicted_torque: torque the model predicts at ``pressure`` with the current
            spline-friction loss [N m]
        reasons: why the command differs from the plain inverse (guard, unreachable ...)

    """

    pressure: float
    steady_state_pressure: float
    correction: float
    predicted_torque: float
    reasons: tuple[str, ...]


def _inverse(params, torque, temperature, slip, reasons):
    from clutch_ros.model import pressure_for_torque

    try:
        return float(pressure_for_torque(params, torque, temperature, slip))
    except ModelError as err:
        reasons.append(f"unreachable torque: {err}")
        return float(params.friction.pressure_ref) * 10.0


def _reference(params, pressure, temperature, slip) -> float:
    from clutch_ros.model import reference_torque

    return abs(float(reference_torque(params, pressure, temperature, slip)))


def command_pressure(params, target_torque: float, lamella_temperature: float,
                     slip_speed: float, *, current_pressure: float = 0.0,
                     modelled_torque: float = math.nan, reference_torque: float = math.nan,
                     correction_gain: float = 1.0, overshoot_margin: float = 0.05,
                     guard_torque: float | None = None) -> ControlCommand:
    """Evaluate the control law (module docstring) for one tick; never returns NaN."""
    reasons: list[str] = []
    guard_torque = target_torque if guard_torque is None else guard_torque
    values = (target_torque, lamella_temperature, slip_speed)
    if not all(math.isfinite(v) for v in values) or target_torque <= 0.0:
        if target_torque > 0.0:
            reasons.append("non-finite input")
        return ControlCommand(0.0, 0.0, 0.0, 0.0, tuple(reasons))
    p_ss = _inverse(params, target_torque, lamella_temperature, slip_speed, reasons)
    correction = 0.0
    loss = 0.0
    if (correction_gain > 0.0 and math.isfinite(modelled_torque)
            and math.isfinite(reference_torque) and math.isfinite(current_pressure)):
        p0 = max(current_pressure, _MIN_SLOPE_PRESSURE)
        dp = 0.01 * p0
        slope = (_reference(params, p0 + dp, lamella_temperature, slip_speed)
                 - _reference(params, p0 - dp, lamella_temperature, slip_speed)) / (2 * dp)
        loss = abs(reference_torque) - abs(modelled_torque)
        if slope > 0.0 and current_pressure > 0.0:
            correction = correction_gain * loss / slope
    pressure = max(p_ss + correction, 0.0)
    guard = _inverse(params, (1.0 + overshoot_margin) * guard_torque, lamella_temperature,
                     slip_speed, [])
    if pressure > guard:
        pressure = guard
        reasons.append("overshoot guard")
    predicted = _reference(params, pressure, lamella_temperature, slip_speed) - loss
    return ControlCommand(pressure, p_ss, correction, max(predicted, 0.0), tuple(reasons))
