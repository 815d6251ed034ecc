"""The ``controller`` node: TorqueRequest (+ RigState, ClutchEstimate) in, PressureCommand out.

At ``controller.rate`` it runs :class:`clutch_ros.model.control.TorqueController` (the same
class the offline closed-loop tests run): the torque target is the request ramped at
``controller.torque_ramp_rate`` and advanced by ``controller.lead_time`` x the request's slope
(without that lead, the pack's viscous lag c/k, the pump lag and the transport delay make the
torque trail a ramp, which shows as overshoot at the low end of falling ramps: 69 % of the
settled time within ±10 % without lead, 100 % with 0.2 s in the offline closed loop on the
rig_truth plant). The target is inverted with the model (steady state with the friction
coefficient's pressure dependence at the estimate's lamella temperature and filtered slip)
plus the estimate's dynamic ``spline_correction``; then, in this order, the overshoot guard
(never above the steady-state inverse of ``(1 + controller.overshoot_margin) x request``),
the pressure limits and the rise/fall rate limits (rises below the pump's kick threshold).

Fail-safe: a stale torque request, stale rig data or a stale/missing estimate (the estimator
died, say) commands 0 Pa at once with ``reason`` saying which; commands resume by themselves
when fresh data returns. Every published pressure is within the configured limits, whatever
arrives (NaN or negative requests are treated as 0 N m and reported).
"""

from __future__ import annotations

from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from clutch_ros.config.presets import default_preset
from clutch_ros.model.control import ControllerSettings, TorqueController
from clutch_ros.nodes.common import (
    Diagnostics,
    LogThrottle,
    ParamSpec,
    declare_params,
    reliable_qos,
    run_node,
    sensor_qos,
)
from clutch_ros.nodes.model_params import apply_model_changes, declare_model_params

NAME = "controller"
PARAMS = [
    ParamSpec("controller.rate", 100.0, "command publishing rate", "Hz", 1.0, 2000.0),
    ParamSpec("controller.min_pressure", 0.0, "lowest commanded pressure", "Pa", 0.0, 1e8),
    ParamSpec("controller.max_pressure", 40e5, "highest commanded pressure", "Pa", 0.0, 1e8),
    ParamSpec("controller.rise_rate_limit", 90e5, "maximum pressure rise; below the pump's "
              "kick threshold (about 100 bar/s, thesis 5.1.1)", "Pa/s", 1.0, 1e10),
    ParamSpec("controller.fall_rate_limit", 400e5, "maximum pressure fall (fail-safe zeroing "
              "bypasses it)", "Pa/s", 1.0, 1e10),
    ParamSpec("controller.torque_ramp_rate", 4000.0, "maximum slew of the torque target "
              "(request ramping)", "N m/s", 1.0, 1e7),
    ParamSpec("controller.lead_time", 0.2, "the target is advanced by lead_time x the request "
              "slope: pack lag c/k (0.1 s), pump lag (~0.05 s) and transport delay", "s",
              0.0, 2.0),
    ParamSpec("controller.lead_max_rate", 1000.0, "bound of the request slope used by the "
              "lead (steps are not differentiated into spikes)", "N m/s", 0.0, 1e6),
    ParamSpec("controller.overshoot_margin", 0.05, "overshoot guard: pressure never above the "
              "steady-state inverse of (1 + margin) x request", "1", 0.0, 1.0),
    ParamSpec("controller.spline_correction_gain", 1.0, "weight of the dynamic spline-friction "
              "correction (0 = steady-state inverse only)", "1", 0.0, 2.0),
    ParamSpec("controller.request_timeout", 0.5, "a torque request older than this is stale "
              "-> 0 Pa", "s", 0.001, 3600.0),
    ParamSpec("controller.rig_timeout", 0.25, "rig_state older than this is stale -> 0 Pa", "s",
              0.001, 3600.0),
    ParamSpec("controller.estimate_timeout", 0.25, "clutch_estimate older than this is stale "
              "-> 0 Pa", "s", 0.001, 3600.0),
]


class ControllerNode(Node):
    """Model-inverting torque-to-pressure controller (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)


        cfg = self._cfg = declare_params(self, PARAMS)
        params = declare_model_params(self, default_preset("flexiforce_8"))
        self._ctl = TorqueController(params, ControllerSettings(
            period=1.0 / cfg["controller.rate"], min_pressure=cfg["controller.min_pressure"],
            max_pressure=cfg["controller.max_pressure"],
            rise_rate_limit=cfg["controller.rise_rate_limit"],
            fall_rate_limit=cfg["controller.fall_rate_limit"],
            torque_ramp_rate=cfg["controller.torque_ramp_rate"],
            lead_time=cfg["controller.lead_time"], lead_max_rate=cfg["controller.lead_max_rate"],
            overshoot_margin=cfg["controller.overshoot_margin"],
            correction_gain=cfg["controller.spline_correction_gain"]))
        self._seen = {"torque request": None, "rig data": None, "estimate": None}
        self._estimate = None
        self._counts = {"commands": 0, "limited": 0, "failsafe": 0, "bad_requests": 0}
        self._last_reason = ""
        self._warn = LogThrottle(5.0)
        self._pub = self.create_publisher(PressureCommand, "pressure_command", reliable_qos())
        # Only the newest sample of each input matters: shallow queues, so a busy moment
        # never leaves the controller working through a backlog of old samples.
        self.create_subscription(TorqueRequest, "torque_request", self._on_request,
                                 reliable_qos(depth=5))
        self.create_subscription(RigState, "rig_state", self._on_rig, sensor_qos())
        self.create_subscription(ClutchEstimate, "clutch_estimate", self._on_estimate,
                                 reliable_qos(depth=2))
        self.create_timer(self._ctl.settings.period, self._tick)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)

    def _on_set_parameters(self, params):
        """Apply model-key changes (validated by the model); controller.* need a restart."""
        fixed = [p.name for p in params if p.name.startswith("controller.")]
        if fixed:
            return SetParametersResult(successful=False, reason=f"{', '.join(fixed)}: "
                                       "controller settings apply at start; restart the node")
        new_params, reason = apply_model_changes(self._ctl.params, params)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        if new_params is not None:
            self._ctl.params = new_params
        return SetParametersResult(successful=True)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_request(self, msg) -> None:
        now = self._now()
        self._seen["torque request"] = now
        warning = self._ctl.set_request(now, msg.torque)
        if warning:
            self._counts["bad_requests"] += 1
            if self._warn.ready():
                self.get_logger().warning(warning)

    def _on_rig(self, msg) -> None:
        self._seen["rig data"] = self._now()

    def _on_estimate(self, msg) -> None:
        self._estimate, self._seen["estimate"] = msg, self._now()

    def _stale_reason(self, now: float) -> str:
        timeouts = {"torque request": "controller.request_timeout",
                    "rig data": "controller.rig_timeout", "estimate": "controller.estimate_timeout"}
        for what, key in timeouts.items():
            at, timeout = self._seen[what], self._cfg[key]
            if at is None:
                return f"no {what} received"
            if now - at > timeout:
                return f"stale {what} ({now - at:.3f} s > {timeout} s)"
        return ""

    def _tick(self) -> None:

        stale = self._stale_reason(self._now())
        if stale:
            out = self._ctl.fail_safe(stale)
            self._counts["failsafe"] += 1
        else:
            est = self._estimate
            out = self._ctl.update(est.lamella_temperature, est.slip_speed_filtered,
                                   est.spline_correction)
        msg = PressureCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.pressure = float(out.pressure)
        msg.requested_torque = float(out.requested_torque)
        msg.predicted_torque = float(out.predicted_torque)
        msg.limited, msg.reason = out.limited, out.reason
        self._counts["commands"] += 1
        self._counts["limited"] += out.limited
        self._last_reason = out.reason
        self._pub.publish(msg)

    def _diagnose(self):
        values = dict(self._counts, pressure_pa=self._ctl.pressure, target_nm=self._ctl.target,
                      last_reason=self._last_reason)
        stale = self._stale_reason(self._now())
        if stale:
            return "WARN", f"fail-safe 0 Pa: {stale}", values
        return "OK", "controlling", values


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros controller``."""
    return run_node(NAME, __doc__, PARAMS, ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
