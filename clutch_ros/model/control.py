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

from clutch_ros.model.errors import ModelError
from clutch_ros.model.inverse import capacity_scalar, solve_pressure

__all__ = ["ControlCommand", "ControllerOutput", "ControllerSettings", "TorqueController",
           "command_pressure"]


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


@dataclass(frozen=True)
class ControllerSettings:
    """Tunables of :class:`TorqueController` (the controller node's parameters, SI).

    Attributes:
        period: control period [s]
        min_pressure, max_pressure: command limits [Pa]
        rise_rate_limit: maximum pressure rise [Pa/s]; below the pump's kick threshold
            (about 100 bar/s, thesis §5.1.1) so steps do not overshoot
        fall_rate_limit: maximum pressure fall [Pa/s] (fail-safe zeroing bypasses it)
        torque_ramp_rate: slew of the torque target [N m/s] (request ramping)
        lead_time: the target is advanced by lead_time x the request slope [s]
        lead_max_rate: bound of the request slope used by the lead [N m/s]
        slope_window: window of the request slope [s]
        overshoot_margin: guard, never above inverse((1 + margin) x request) [1]
        correction_gain: weight of the spline-friction correction [1]

    """

    period: float = 0.01
    min_pressure: float = 0.0
    max_pressure: float = 40e5
    rise_rate_limit: float = 90e5
    fall_rate_limit: float = 400e5
    torque_ramp_rate: float = 4000.0
    lead_time: float = 0.2
    lead_max_rate: float = 1000.0
    slope_window: float = 0.1
    overshoot_margin: float = 0.05
    correction_gain: float = 1.0

    def __post_init__(self) -> None:
        checks = {"period": self.period > 0.0, "rise_rate_limit": self.rise_rate_limit > 0.0,
                  "fall_rate_limit": self.fall_rate_limit > 0.0,
                  "torque_ramp_rate": self.torque_ramp_rate > 0.0,
                  "lead_time": self.lead_time >= 0.0, "lead_max_rate": self.lead_max_rate >= 0.0,
                  "slope_window": self.slope_window > 0.0,
                  "overshoot_margin": self.overshoot_margin >= 0.0,
                  "correction_gain": self.correction_gain >= 0.0,
                  "min_pressure": 0.0 <= self.min_pressure <= self.max_pressure}
        for name, ok in checks.items():
            if not ok or not math.isfinite(getattr(self, name)):
                raise ModelError(f"controller setting {name} out of range: "
                                 f"{getattr(self, name)!r}")


@dataclass(frozen=True)
class ControllerOutput:
    """One controller tick: the command and why it is what it is (SI units)."""

    pressure: float
    requested_torque: float
    predicted_torque: float
    limited: bool
    reason: str


class TorqueController:
    """Stateful torque-to-pressure controller: ramp, lead, control law, limits.

    The controller node and the offline closed loop (:mod:`clutch_ros.offline.closed_loop`) both
    run this class, so what is tested offline is what runs on the rig. Per tick
    (:meth:`update`): the target ramps towards the request at ``torque_ramp_rate``, is advanced
    by ``lead_time`` x the request slope, goes through :func:`command_pressure`, then the
    pressure limits and the rise/fall rate limits. :meth:`fail_safe` commands 0 Pa at once.
    """

    def __init__(self, params, settings: ControllerSettings | None = None):
        self.params = params
        self.settings = settings or ControllerSettings()
        self.target = 0.0  # [N m]
        self.pressure = 0.0  # [Pa], last command
        self.request = 0.0  # [N m]
        self._history: list[tuple[float, float]] = []

    def set_request(self, t: float, torque: float) -> str:
        """Record a torque request at time ``t`` [s]; return a warning for a bad value."""
        warning = ""
        if not math.isfinite(torque) or torque < 0.0:
            warning = f"torque request {torque!r} N m is not a finite value >= 0; using 0 N m"
            torque = 0.0
        self.request = torque
        self._history.append((t, torque))
        window = self.settings.slope_window
        while len(self._history) > 2 and t - self._history[1][0] >= window:
            self._history.pop(0)
        return warning

    def request_slope(self) -> float:
        """Slope of the request over the last ``slope_window`` [N m/s], bounded."""
        if len(self._history) < 2:
            return 0.0
        (t0, r0), (t1, r1) = self._history[0], self._history[-1]
        if t1 - t0 < 0.5 * self.settings.slope_window:
            return 0.0
        bound = self.settings.lead_max_rate
        return max(-bound, min(bound, (r1 - r0) / (t1 - t0)))

    def fail_safe(self, reason: str) -> ControllerOutput:
        """Command 0 Pa now (no rate limit) and forget the ramp state."""
        self.target = 0.0
        self.pressure = 0.0
        return ControllerOutput(0.0, self.request, 0.0, True, f"fail-safe: {reason}")

    def update(self, lamella_temperature: float, slip_speed: float,
               spline_correction: float = 0.0) -> ControllerOutput:
        """Run one tick; inputs are the estimator's latest values.

        Args:
            lamella_temperature: [°C]
            slip_speed: filtered slip speed [rad/s]
            spline_correction: the estimate's spline correction [Pa]

        """
        s = self.settings
        step = s.torque_ramp_rate * s.period
        self.target += max(-step, min(step, self.request - self.target))
        lead = s.lead_time * self.request_slope()
        cmd = command_pressure(self.params, max(self.target + lead, 0.0), lamella_temperature,
                               slip_speed, spline_correction=spline_correction,
                               correction_gain=s.correction_gain,
                               overshoot_margin=s.overshoot_margin, guard_torque=self.request)
        reasons = list(cmd.reasons)
        if self.target != self.request:
            reasons.append("request ramping")
        pressure = min(max(cmd.pressure, s.min_pressure), s.max_pressure)
        if pressure != cmd.pressure:
            reasons.append("pressure limit")
        rise, fall = s.rise_rate_limit * s.period, s.fall_rate_limit * s.period
        limited = self.pressure + max(-fall, min(rise, pressure - self.pressure))
        if limited != pressure:
            reasons.append("rate limit")
        self.pressure = limited
        return ControllerOutput(limited, self.request, cmd.predicted_torque, bool(reasons),
                                "; ".join(reasons))
