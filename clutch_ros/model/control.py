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

:class:`TorqueController` adds two things on top of the law:

- the adapted model: :meth:`TorqueController.set_model_scale` inverts the model with μ (and
  the spline gain) scaled by the estimator's adapted values
  (:func:`clutch_ros.model.adaptation.scaled_params`), so the feed-forward is the adapted
  model's inverse. A new scale is taken when the request changes (steps, ramps) or is 0,
  not in the middle of a hold (``scale_hold``): there the trim integrates, and two
  integrators on one error would fight;
- an optional integral trim on the measured torque, in internal-model form: the trim ``u``
  (a fraction of the request) integrates the model's relative error at the current
  operating point, ``du/dt = trim_rate · ((|T_model| − |T_meas|) / T* − u)``, and the law
  inverts the target plus ``u · T*`` (the overshoot guard moves with it). ``T_model`` and
  ``T_meas`` are the estimate's modelled and measured torque *at the same sample*, both
  answers to the same actuating pressure, so the error the trim integrates carries no pump
  or transport lag; at steady state ``T_model(p) = T* + u T*`` and ``u T* = T_model − T_meas``
  give ``T_meas = T*``: no steady-state error for any constant model error (the integral
  property), while the loop sees no extra lag (a plain integral of ``T* − T_meas`` winds up
  against the pump and pack lag and the coulomb spline friction's stick: tried, it overshot).
  Anti-windup: ``|u| <= trim_limit`` (without caution; with it, ``1 + u`` within
  ``(1 + u_c)(1 ± trim_limit)``, ``u_c`` below); ``u`` holds (does not integrate) while the
  command is clamped (pressure or rate limits) in the direction the error pushes and for
  ``trim_delay`` after a step of the request (the pack's step transient is the model
  dynamics' error);
  it is released to 0 at a step when ``trim_reset_on_change``, without a torque measurement
  for longer than ``trim_hold`` (off: the adapted model alone; a shorter gap, a late CAN
  frame, only holds it), with ``trim_rate`` 0 and at a 0 N m request. The trimmed
  pressure still goes through the pressure limits, so it never leaves them;
  :attr:`ControllerOutput.trim_pressure` is the trim's share of the published pressure;
- caution while μ is unlearned: while the trim can act (a torque measurement, ``trim_rate``
  > 0), the friction scale inverted is the upper confidence bound ``s_c = s + m σ_s`` of the
  adapted scale ``s`` (``σ_s`` its standard deviation, ``m`` ``uncertainty_margin``). Torque
  is proportional to μ, so at a step the torque then rises towards ``(s_true / s_c) T*``, below
  the request unless μ is more than ``m σ_s`` above its estimate, and the trim (same cautious
  model, so the integral property holds) closes the gap from below after ``trim_delay``;
  its bound is centred on ``u_c = s_c / s − 1``, the trim that undoes the caution, so
  ``trim_limit`` still bounds the model's relative error only (the same plants are reachable
  with and without caution). Why from below: on the rig's pack an overshoot decays slowly
  (the spline friction holds a compressed pack; torque is hysteretic in pressure), and an
  overshoot is the worse failure. Before anything is learned ``σ_s`` is the adaptation's
  prior (0.2: 10 % caution at ``m`` = 0.5); a few seconds of adaptation take it below 0.005
  and the caution vanishes. The start (``uncertainty_range`` R): at the prior's σ μ may be
  anywhere in ``s ± R σ``, so the caution is at least ``(s + R σ) / (1 + overshoot_margin)
  − s`` (R = 2: 0.33), the trim's bounds reach every plant of that range and it acts after
  ``start_trim_delay``: no μ within 2 σ overshoots the first step by more than 5 %.
  Without a measurement it is 0 (nothing would close the gap;
  dropped at once when the trim is released).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from clutch_ros.model.adaptation import scaled_params
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.model.inverse import capacity_scalar, solve_pressure

if TYPE_CHECKING:
    from clutch_ros.model.params import ClutchParams

__all__ = ["ControlCommand", "ControllerOutput", "TorqueController", "command_pressure"]


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


def command_pressure(params: ClutchParams, target_torque: float, lamella_temperature: float,
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
class ControllerOutput:
    """One controller tick: the command and why it is what it is (SI units).

    ``trim_pressure`` [Pa] is the integral trim's share of ``pressure`` (0 when off).
    """

    pressure: float
    requested_torque: float
    predicted_torque: float
    limited: bool
    reason: str
    trim_pressure: float = 0.0


class TorqueController:
    """Stateful torque-to-pressure controller: ramp, lead, control law, trim, limits.

    The controller node and the offline closed loop (:mod:`clutch_ros.offline.closed_loop`) both
    run this class, so what is tested offline is what runs on the rig. Per tick
    (:meth:`update`): the target ramps towards the request at ``torque_ramp_rate``, is advanced
    by ``lead_time`` x the request slope, goes through :func:`command_pressure` on the
    (adapted) model, gets the integral trim (module docstring), then the pressure limits and
    the rise/fall rate limits. :meth:`fail_safe` commands 0 Pa at once.
    """

    def __init__(self, params: ClutchParams, settings: ControllerSettings | None = None):
        self.base_params = params
        self.params = params
        self.settings = settings or ControllerSettings()
        self.friction_scale = 1.0  # [1] applied to self.params (caution included)
        self.caution = 0.0  # [1] of it, the uncertainty margin above the estimate's scale
        self.spread = 0.0  # [1] uncertainty_range x σ_s of the scale inverted (0: no caution)
        self._start = False  # the caution is the start's (uncertainty_range): start_trim_delay
        self.spline_gain_scale = 1.0  # [1]
        self.target = 0.0  # [N m]
        self.pressure = 0.0  # [Pa], last command
        self.request = 0.0  # [N m]
        self.trim = 0.0  # [1] relative trim u
        self._changed_at = -math.inf  # [s] last change of the request
        self._now = -math.inf  # [s] time of the last request
        self._stamp = -math.inf  # [s] its own stamp
        self._history: list[tuple[float, float]] = []
        self._pending: tuple[float, float, float] | None = None
        self._moved = True  # the request changed since the last tick
        # [s] the torque measurement has been missing this long (none seen yet: forever)
        self._missing_for = math.inf
        # the first inversion imports scipy.optimize (0.2-0.7 s): here, at start, not in the
        # control tick of the first step (a node stalled that long there, then fail-safe)
        solve_pressure(params, 1.0, 20.0, 1.0)

    def set_base_params(self, params: ClutchParams) -> None:
        """Replace the model parameters (scale 1); the adapted scales are re-applied."""
        self.base_params = params
        self._rescale(self.friction_scale, self.spline_gain_scale)

    def set_model_scale(self, friction_scale: float, spline_gain_scale: float = 1.0,
                        friction_scale_std: float = 0.0) -> None:
        """Invert the model with μ x ``friction_scale`` and gain x ``spline_gain_scale``.

        ``friction_scale_std`` [1] is the adaptation's standard deviation of the friction
        scale: while the trim can act (a torque measurement within ``trim_hold``,
        ``trim_rate`` > 0), the scale inverted is its upper confidence bound
        ``friction_scale + uncertainty_margin · friction_scale_std`` (:meth:`_caution`).
        Ignored for non-finite or non-positive scales (a non-finite or negative std counts
        as 0). With ``scale_hold`` the new scales wait for the next change of the request
        (module docstring); re-inverts only when a scale moved by more than
        ``scale_tolerance`` (scaled parameters cost ~0.5 ms).
        """
        values = (friction_scale, spline_gain_scale)
        if all(math.isfinite(v) and v > 0.0 for v in values):
            std = friction_scale_std if math.isfinite(friction_scale_std) else 0.0
            self._pending = (friction_scale, spline_gain_scale, max(std, 0.0))

    def _caution(self, friction_scale_std: float, friction_scale: float = 1.0) -> float:
        """Return the margin [1] added to the friction scale inverted (0: none).

        Why: the torque is proportional to μ, so inverting the model at the upper confidence
        bound of μ makes the first torque of a step fall short of the request rather than
        exceed it when μ is not yet learned (overshoot is the worse failure, thesis §1.2;
        the coulomb spline friction holds an over-compressed pack, so an overshoot decays
        slowly). The integral trim, whose internal model is the same cautious model, then
        closes the gap from below; the margin shrinks with σ as the adaptation learns. Only
        while the trim can act: without a measurement nothing would close the gap, and the
        best estimate is the better feed-forward.

        The start (``uncertainty_range``): before anything is learned σ is the prior's, and
        μ may be anywhere in ``s ± range σ``; the margin is at least what keeps the top of
        that range within ``overshoot_margin`` of the request, ``(s + range σ) / (1 +
        overshoot_margin) − s`` (with the prior 0.2 and range 2: 0.33, against 0.1 from
        ``uncertainty_margin``). It is positive only while σ is large: learned (σ below
        ~0.02), ``uncertainty_margin σ`` is the larger, and the learned steps are unchanged.
        """
        s = self.settings
        if s.trim_rate <= 0.0 or self._missing_for > s.trim_hold + 1e-9:
            return 0.0
        top = friction_scale + s.uncertainty_range * friction_scale_std
        start = top / (1.0 + s.overshoot_margin) - friction_scale
        return max(s.uncertainty_margin * friction_scale_std, start, 0.0)

    def _apply_pending(self) -> None:
        if self._pending is None:
            return
        estimated, spline_gain_scale, std = self._pending
        caution = self._caution(std, estimated)
        friction_scale = estimated + caution
        tol = self.settings.scale_tolerance
        if (abs(friction_scale - self.friction_scale) > tol * self.friction_scale
                or abs(spline_gain_scale - self.spline_gain_scale)
                > tol * self.spline_gain_scale):
            self._rescale(friction_scale, spline_gain_scale)
        self.caution = self.friction_scale - estimated
        self.spread = self.settings.uncertainty_range * std if self.caution > 0.0 else 0.0
        # the start's term set the caution (not uncertainty_margin's): a start's step
        self._start = self.caution > self.settings.uncertainty_margin * std + 1e-12
        self._pending = None

    def _rescale(self, friction_scale: float, spline_gain_scale: float) -> None:
        self.params = (self.base_params if friction_scale == 1.0 and spline_gain_scale == 1.0
                       else scaled_params(self.base_params, friction_scale, spline_gain_scale))
        self.friction_scale, self.spline_gain_scale = friction_scale, spline_gain_scale

    def set_request(self, t: float, torque: float, stamp: float | None = None) -> str:
        """Record a torque request received at time ``t`` [s]; return a warning for a bad value.

        ``stamp`` [s]: the request's own time (its header stamp; None: ``t``), which dates the
        change for the step test (``step_threshold``), so requests delivered in a bunch keep
        the spacing they were published with.
        """
        warning = ""
        if not math.isfinite(torque) or torque < 0.0:
            warning = f"torque request {torque!r} N m is not a finite value >= 0; using 0 N m"
            torque = 0.0
        stamp = t if stamp is None else stamp
        if torque != self.request:
            self._moved = True
            change = abs(torque - self.request)
            elapsed = stamp - self._stamp if math.isfinite(self._stamp) else 0.0  # 1st: step
            if (change > self.settings.step_threshold * max(torque, self.request)
                    and not change <= self.settings.lead_max_rate * elapsed):
                self._changed_at = t
                if self.settings.trim_reset_on_change:
                    self.trim = 0.0
        self._stamp = stamp
        self.request = torque
        self._now = t
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
        """Command 0 Pa now (no rate limit) and forget the ramp and trim state."""
        self.target = 0.0
        self.pressure = 0.0
        self.trim = 0.0
        return ControllerOutput(0.0, self.request, 0.0, True, f"fail-safe: {reason}")

    def _trim_state(self, measured_torque: float, modelled_torque: float,
                    modelled_scale: float) -> str:
        """Return '' when the trim may integrate now, 'hold', or why it is off."""
        s = self.settings
        if s.trim_rate <= 0.0:
            return "trim off"
        if not (math.isfinite(measured_torque) and math.isfinite(modelled_torque)
                and modelled_scale > 0.0):
            self._missing_for += s.period
            held = self._missing_for <= s.trim_hold + 1e-9  # float sum of periods
            return "hold" if held else "no torque measurement"
        self._missing_for = 0.0
        if self.request <= 0.0:
            return "no request"
        since = self._now - self._changed_at
        if since < (min(s.trim_delay, s.start_trim_delay) if self._start else s.trim_delay):
            return "hold"
        low, high = self._trim_bounds()
        error = self._trim_error(measured_torque, modelled_torque, modelled_scale)
        if since < s.trim_settle_time and not low <= error <= high:
            return "hold"  # still in the step's transient: beyond what the trim may correct
        return ""

    def _trim_error(self, measured_torque: float, modelled_torque: float,
                    modelled_scale: float) -> float:
        """Return the relative error the trim integrates: (own model - measured) / request."""
        own = abs(modelled_torque) * self.friction_scale / modelled_scale
        return (own - abs(measured_torque)) / self.request

    def _trim_bounds(self) -> tuple[float, float]:
        """Return the trim's bounds [1]: ±trim_limit around the trim undoing the caution.

        Centred on 1 + u_c = s_c / s: the limit is on the model's relative error, not on the
        margin put in on purpose. With ``uncertainty_range`` the bounds also reach every
        plant of ``s ± range σ`` (``1 + u = s_c / s_true``; the lower end of the range
        floored at s / 2): the start's plants, however far μ is from its unlearned estimate.
        """
        limit = self.settings.trim_limit
        low, high = -limit, limit
        if self.caution:
            scale = self.friction_scale - self.caution  # the estimate s
            top, bottom = scale + self.spread, max(scale - self.spread, 0.5 * scale)
            low = self.friction_scale / top * (1.0 - limit) - 1.0
            high = self.friction_scale / bottom * (1.0 + limit) - 1.0
        return low, high

    def update(self, lamella_temperature: float, slip_speed: float,
               spline_correction: float = 0.0, measured_torque: float = math.nan,
               modelled_torque: float = math.nan,
               modelled_scale: float = 1.0) -> ControllerOutput:
        """Run one tick; inputs are the estimator's latest values.

        Args:
            lamella_temperature: [°C]
            slip_speed: filtered slip speed [rad/s]
            spline_correction: the estimate's spline correction [Pa]
            measured_torque: the estimate's measured torque [N m] (NaN: none; trim off)
            modelled_torque: the estimate's modelled torque, same sample [N m]
            modelled_scale: the friction scale that modelled torque was computed with [1];
                the trim compares the measurement with *this controller's* model, so the
                modelled torque is rescaled to ``friction_scale`` (torque ∝ μ)

        """
        s = self.settings
        if not s.scale_hold or self._moved or self.request <= 0.0:
            self._apply_pending()
        self._moved = False
        step = s.torque_ramp_rate * s.period
        self.target += max(-step, min(step, self.request - self.target))
        slope = self.request_slope()
        lead = (s.lead_time if slope >= 0.0 else s.fall_lead_time) * slope
        state = self._trim_state(measured_torque, modelled_torque, modelled_scale)
        if state and state != "hold":
            self.trim = 0.0  # off: released at once (the adapted model alone)
            if self.caution and state != "no request":  # nothing would close the gap
                self._rescale(self.friction_scale - self.caution, self.spline_gain_scale)
                self.caution = self.spread = 0.0
                self._start = False
        extra = self.trim * self.request
        base = max(self.target + lead, 0.0)
        cmd = command_pressure(self.params, base + extra if base > 0.0 else 0.0,
                               lamella_temperature, slip_speed,
                               spline_correction=spline_correction,
                               correction_gain=s.correction_gain,
                               overshoot_margin=s.overshoot_margin,
                               guard_torque=self.request + extra)
        untrimmed = cmd.pressure
        if extra != 0.0:
            untrimmed = command_pressure(self.params, base, lamella_temperature, slip_speed,
                                         spline_correction=spline_correction,
                                         correction_gain=s.correction_gain,
                                         overshoot_margin=s.overshoot_margin,
                                         guard_torque=self.request).pressure
        reasons = list(cmd.reasons)
        if self.target != self.request:
            reasons.append("request ramping")
        pressure = min(max(cmd.pressure, s.min_pressure), s.max_pressure)
        if pressure != cmd.pressure:
            reasons.append("pressure limit")
        rise, fall = s.rise_rate_limit * s.period, s.fall_rate_limit * s.period
        limited = self.pressure + max(-fall, min(rise, pressure - self.pressure))
        # the limits win over the rate limits (a start from 0 Pa below min_pressure)
        limited = min(max(limited, s.min_pressure), s.max_pressure)
        if limited != pressure:
            reasons.append("rate limit")
        if not state:
            error = self._trim_error(measured_torque, modelled_torque, modelled_scale)
            pushes_up = error > self.trim
            clamped = (limited < cmd.pressure and pushes_up) or \
                (limited > cmd.pressure and not pushes_up)
            if not clamped:  # anti-windup: conditional integration
                gain = min(1.0, s.trim_rate * s.period)
                self.trim += gain * (error - self.trim)
                low, high = self._trim_bounds()
                self.trim = max(low, min(high, self.trim))
        # the trim's share: this command minus the one the same tick gives without it
        free = min(max(untrimmed, s.min_pressure), s.max_pressure)
        free = self.pressure + max(-fall, min(rise, free - self.pressure))
        free = min(max(free, s.min_pressure), s.max_pressure)
        share = limited - free
        self.pressure = limited
        return ControllerOutput(limited, self.request, cmd.predicted_torque, bool(reasons),
                                "; ".join(reasons), share)
