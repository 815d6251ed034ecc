"""Torque-to-pressure control law: model inverse, spline-friction correction, overshoot guard.

Pure functions used by the controller node (and testable without ROS). Units: torque [N m],
pressure [Pa], temperature [°C], slip speed [rad/s].

The law, for a torque target ``T*``:

1. steady-state inverse plus dynamic correction,
   :func:`clutch_ros.model.inverse.solve_pressure`: ``p = inverse(T*) + g * c`` where ``c``
   is the estimator's ``spline_correction`` (the pressure equivalent of the pack's current
   spline-friction loss, :meth:`PackModel.spline_correction`: positive while the pack is
   compressed against spline friction, negative while friction holds it compressed on
   rebound) and ``g`` the correction gain. Choice: the correction is the one of the
   estimator's pack *now*, not re-simulated at the new pressure: the spline-friction state
   changes slowly compared with the control period, and it keeps the law O(1) per tick;
2. overshoot guard: the pressure never exceeds ``inverse((1 + margin) * guard_torque)`` (the
   plain steady-state inverse, no correction), since overshoot is the worse failure
   (thesis §1.2);
3. a request of 0 N m (or below, or non-finite) commands 0 Pa.

Limits and rate limits on the pressure are the caller's (node parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clutch_ros.model.inverse import capacity_scalar, solve_pressure

__all__ = ["ControlCommand", "command_pressure"]


@dataclass(frozen=True)
class ControlCommand:
    """Result of one control-law evaluation.

    Attributes:
        pressure: commanded actuating pressure before node limits [Pa]
        steady_state_pressure: the steady-state inverse of the target [Pa]
        correction: spline-friction correction applied [Pa]
        predicted_torque: steady-state torque of the model at ``pressure`` less the current
            spline-friction loss [N m]
        reasons: why the command differs from the plain inverse (guard, unreachable ...)

    """

    pressure: float
    steady_state_pressure: float
    correction: float
    predicted_torque: float
    reasons: tuple[str, ...]


def command_pressure(params, target_torque: float, lamella_temperature: float,
                     slip_speed: float, *, spline_correction: float = 0.0,
                     correction_gain: float = 1.0, overshoot_margin: float = 0.05,
                     guard_torque: float | None = None) -> ControlCommand:
    """Evaluate the control law (module docstring) for one tick; never returns NaN."""
    guard_torque = target_torque if guard_torque is None else guard_torque
    values = (target_torque, lamella_temperature, slip_speed, guard_torque)
    if not all(math.isfinite(v) for v in values):
        return ControlCommand(0.0, 0.0, 0.0, 0.0, ("non-finite input",))
    if target_torque <= 0.0:
        return ControlCommand(0.0, 0.0, 0.0, 0.0, ())
    correction = correction_gain * spline_correction if math.isfinite(spline_correction) \
        else 0.0
    sol = solve_pressure(params, target_torque, lamella_temperature, slip_speed, correction)
    reasons = [sol.reason] if sol.reason else []
    pressure = sol.pressure
    guard = solve_pressure(params, (1.0 + overshoot_margin) * guard_torque,
                           lamella_temperature, slip_speed).steady_state_pressure
    if pressure > guard:
        pressure = guard
        reasons.append("overshoot guard")
    applied = pressure - sol.steady_state_pressure
    predicted = capacity_scalar(params, pressure - correction, lamella_temperature, slip_speed)
    return ControlCommand(pressure, sol.steady_state_pressure, applied, predicted,
                          tuple(reasons))
