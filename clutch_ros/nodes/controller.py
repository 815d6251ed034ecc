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

Fail-safe: no ``torque_request`` for ``controller.request_timeout`` (0.5 s), no ``rig_state``
for ``controller.rig_timeout`` (0.25 s) or no ``clutch_estimate`` for
``controller.estimate_timeout`` (0.25 s), or none received yet, commands 0 Pa at once (no
rate limit) with ``reason`` naming the input and the silent node, read from the ROS graph
(``fail-safe: stale estimate: no clutch_estimate from /estimator for 0.31 s (> 0.25 s)``, see
:mod:`clutch_ros.nodes.peers`); the check runs every tick (``1/controller.rate``), so 0 Pa
follows at most one period after a timeout. Commands resume by themselves when fresh data
returns.

Trigger (``controller.trigger``, read-only): ``timer`` runs a step every ``1/controller.rate``
on the newest estimate; ``estimate`` runs one step per ``clutch_estimate`` as it arrives and
stamps the command with the estimate's stamp, so the command names the estimate it answers
(lock-step: the rig waits for the command of its tick, :mod:`clutch_ros.nodes.lockstep`) and
the node wakes once per command less. ``controller.rate`` is then the estimates' rate (the
rate limits and the trim advance one period per step; an estimate stamped less than half a
period after the last answered one is skipped, counted ``skipped``), and a watchdog timer every
``WATCHDOG_FRACTION`` of the shortest input timeout commands 0 Pa (fail-safe, as above) when no
step ran for that long and an input is stale: 0 Pa follows at most 1.25 timeouts after the
estimate stopped. Every published pressure is within the configured limits, whatever arrives (NaN or
negative requests are treated as 0 N m and reported).

Adapted model and trim: the target is inverted with μ scaled by the estimate's adapted
``friction_scale`` (``controller.use_adapted_model``; a new scale is taken when the request
changes, never during a hold) and, while the estimate carries a measured torque, an integral
trim on it (``controller.trim_rate``, ``controller.trim_limit``, ``controller.trim_delay``;
:class:`~clutch_ros.model.control.TorqueController` documents the law and its anti-windup)
removes what the model still gets wrong; without a measurement it is off. While the trim
can act, the scale inverted is the upper confidence bound ``friction_scale +
controller.uncertainty_margin x friction_scale_std`` (the estimate's standard deviation), so a
step before anything is learned approaches the request from below and the trim closes the
gap (``caution`` in ``/diagnostics``). The trim's share of every command is
``PressureCommand.trim_pressure`` [Pa]; the limits still bound it.

Parameters: every ``controller.*`` setting and every model key applies live (the next tick)
after validation: ranges by ROS, ``min_pressure <= max_pressure`` and the model's rules here;
a refused change names its reason and changes nothing.
"""

from __future__ import annotations

from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from clutch_ros.config.presets import default_preset
from clutch_ros.errors import ClutchError
from clutch_ros.interfaces import CLUTCH_ESTIMATE, PRESSURE_COMMAND, RIG_STATE, TORQUE_REQUEST
from clutch_ros.model.control import TorqueController
from clutch_ros.nodes.controller_params import (
    PARAMS,
    TIMEOUTS,
    TRIGGERS,
    WATCHDOG_FRACTION,
    controller_settings,
)
from clutch_ros.nodes.diagnostics import Diagnostics, LogThrottle
from clutch_ros.nodes.model_params import apply_model_changes, declare_model_params
from clutch_ros.nodes.parameters import declare_params
from clutch_ros.nodes.peers import Input, PeerWatch
from clutch_ros.nodes.qos import publisher_qos, sensor_qos, subscriber_qos
from clutch_ros.nodes.runner import run_node
from clutch_ros.nodes.stamps import stamp_to_sec

NAME = "controller"


class ControllerNode(Node):
    """Model-inverting torque-to-pressure controller (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        cfg = self._cfg = declare_params(self, PARAMS)
        if cfg["controller.trigger"] not in TRIGGERS:
            raise ClutchError(f"controller.trigger must be one of {'|'.join(TRIGGERS)}, got "
                              f"{cfg['controller.trigger']!r}")
        self._on_estimates = cfg["controller.trigger"] == "estimate"
        params = declare_model_params(self, default_preset("flexiforce_8"))
        self._ctl = TorqueController(params, controller_settings(cfg))
        self._peers = PeerWatch(self, [
            Input("torque request", TORQUE_REQUEST.name, cfg["controller.request_timeout"],
                  "a torque-request source"),
            Input("rig data", RIG_STATE.name, cfg["controller.rig_timeout"],
                  RIG_STATE.publisher_node),
            Input("estimate", CLUTCH_ESTIMATE.name, cfg["controller.estimate_timeout"],
                  CLUTCH_ESTIMATE.publisher_node)])
        self._estimate = None
        self._counts = {"commands": 0, "limited": 0, "failsafe": 0, "bad_requests": 0,
                        "skipped": 0}
        self._stepped_ns = -1  # [ns] stamp of the last estimate a step answered
        self._stepped_at = -1e300  # [s] node clock at the last step
        self._last_reason = ""
        self._warn = LogThrottle(5.0)
        self._pub = self.create_publisher(PressureCommand, PRESSURE_COMMAND.name,
                                          publisher_qos(PRESSURE_COMMAND.name))
        # QoS (interfaces.TOPICS): inputs: torque requests are commands, so reliable (depth
        # 5: only the newest matters); rig_state and clutch_estimate are state of which only
        # the latest sample is used: sensor-data QoS (best effort, depth 5), which matches
        # reliable and best-effort publishers alike.
        self.create_subscription(TorqueRequest, TORQUE_REQUEST.name, self._on_request,
                                 subscriber_qos(TORQUE_REQUEST.name, depth=5))
        # raw: only the arrival of rig_state counts here; not deserialising it saves the
        # message construction (~30 fields) on every sample
        self.create_subscription(RigState, RIG_STATE.name, self._on_rig, sensor_qos(), raw=True)
        # (estimate trigger: every estimate is answered, so none may be dropped: the topic's
        # reliable subscriber profile)
        self.create_subscription(ClutchEstimate, CLUTCH_ESTIMATE.name, self._on_estimate,
                                 subscriber_qos(CLUTCH_ESTIMATE.name) if self._on_estimates
                                 else sensor_qos())
        # one PressureCommand, refilled per tick (publish serialises it before it returns)
        self._cmd = PressureCommand()
        # the node clock's C handle: node time (ROS time, /clock with use_sim_time) without a
        # rclpy Time object per call
        self._clock_handle = self.get_clock().handle
        # use_sim_time: node time is never earlier than the newest request or estimate stamp
        # (a message stamped T proves that /clock reached T, whether or not this node's /clock
        # arrived first: the same time on every lock-step run, as the bridge's node time)
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        self._time_floor = 0.0  # [s]
        self._timer = self._make_timer()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)

    def _on_set_parameters(self, params):
        """Validate and apply controller.* and model keys at once (all or nothing).

        ROS checks each value against its descriptor's range first; here the set as a whole
        is checked (``min_pressure <= max_pressure``, the model's own rules). Accepted
        settings apply from the next tick: a lower ``max_pressure`` also clamps the pressure
        held now, so no later command exceeds it; a new ``rate`` restarts the timer.
        """
        own = {p.name: p.value for p in params if p.name.startswith("controller.")}
        cfg = {**self._cfg, **own}
        if cfg["controller.min_pressure"] > cfg["controller.max_pressure"]:
            return SetParametersResult(successful=False, reason=(
                f"controller.min_pressure {cfg['controller.min_pressure']} Pa must not exceed "
                f"controller.max_pressure {cfg['controller.max_pressure']} Pa"))
        try:
            settings = controller_settings(cfg)
        except ClutchError as err:
            return SetParametersResult(successful=False, reason=str(err))
        new_params, reason = apply_model_changes(self._ctl.params, params)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        if new_params is not None:
            self._ctl.set_base_params(new_params)
        if own:
            period_changed = settings.period != self._ctl.settings.period
            self._cfg = cfg
            self._ctl.settings = settings
            self._ctl.pressure = min(max(self._ctl.pressure, settings.min_pressure),
                                     settings.max_pressure)
            for what, key in TIMEOUTS.items():
                self._peers.set_timeout(what, cfg[key])
            if period_changed or self._on_estimates:  # (the watchdog's follows the timeouts)
                self.destroy_timer(self._timer)
                self._timer = self._make_timer()
            self.get_logger().info("controller settings changed: " + ", ".join(
                f"{k}={v}" for k, v in sorted(own.items())))
        return SetParametersResult(successful=True)

    def _make_timer(self):
        if self._on_estimates:
            return self.create_timer(self._watchdog_period(), self._watchdog)
        return self.create_timer(self._ctl.settings.period, self._tick)

    def _watchdog_period(self) -> float:
        return WATCHDOG_FRACTION * min(self._cfg[key] for key in TIMEOUTS.values())

    def _now(self) -> float:
        now = self._clock_handle.get_now().nanoseconds * 1e-9
        return max(now, self._time_floor) if self._sim_time else now

    def _saw(self, stamp: float) -> None:
        if self._sim_time and stamp > self._time_floor:
            self._time_floor = stamp

    def _on_request(self, msg) -> None:
        stamp = stamp_to_sec(msg.header.stamp)
        self._saw(stamp)
        now = self._now()
        self._peers.seen("torque request", now)
        warning = self._ctl.set_request(now, msg.torque, stamp if stamp > 0.0 else None)
        if warning:
            self._counts["bad_requests"] += 1
            if self._warn.ready():
                self.get_logger().warning(warning)

    def _on_rig(self, msg) -> None:
        self._peers.seen("rig data", self._now())

    def _on_estimate(self, msg) -> None:
        self._estimate = msg
        ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        self._saw(ns * 1e-9)
        now = self._now()
        self._peers.seen("estimate", now)
        if self._on_estimates:
            if ns - self._stepped_ns < 0.5e9 * self._ctl.settings.period:
                self._counts["skipped"] += 1  # faster than controller.rate, or out of order
                return
            self._stepped_at, self._stepped_ns = now, ns
            self._step(now, ns)

    def _watchdog(self) -> None:
        """Estimate trigger: the fail-safe when no step ran for a watchdog period."""
        now = self._now()
        if now - self._stepped_at >= self._watchdog_period() and self._stale_reason(now):
            self._step(now, max(self._clock_handle.get_now().nanoseconds,
                                round(self._time_floor * 1e9)))

    def _stale_reason(self, now: float) -> str:
        return self._peers.silent(now)

    def _tick(self) -> None:
        self._step(self._now(), self._clock_handle.get_now().nanoseconds)

    def _step(self, now: float, stamp_ns: int) -> None:
        """Compute and publish one command stamped ``stamp_ns`` [ns] at node time ``now``."""
        stale = self._stale_reason(now)
        est = self._estimate
        if stale or est is None:  # (no estimate yet: the peer check reports it silent)
            out = self._ctl.fail_safe(stale or "no estimate yet")
            self._counts["failsafe"] += 1
        else:
            # scale 0 = an estimator without adaptation fields (the message default): scale 1
            scale = est.friction_scale if est.friction_scale > 0.0 else 1.0
            if self._cfg["controller.use_adapted_model"]:
                gain = est.spline_gain_scale if est.spline_gain_scale > 0.0 else 1.0
                self._ctl.set_model_scale(scale, gain, est.friction_scale_std)
            else:
                self._ctl.set_model_scale(1.0, 1.0)
            out = self._ctl.update(est.lamella_temperature, est.slip_speed_filtered,
                                   est.spline_correction, est.measured_torque,
                                   est.modelled_torque, scale)
        msg = self._cmd
        stamp = msg.header.stamp  # as Time.to_msg(): seconds and nanoseconds (node clock or
        stamp.sec, stamp.nanosec = divmod(stamp_ns, 10**9)  # the answered estimate's stamp)
        msg.pressure = float(out.pressure)
        msg.requested_torque = float(out.requested_torque)
        msg.predicted_torque = float(out.predicted_torque)
        msg.limited, msg.reason = out.limited, out.reason
        msg.trim_pressure = float(out.trim_pressure)
        self._counts["commands"] += 1
        self._counts["limited"] += out.limited
        self._last_reason = out.reason
        self._pub.publish(msg)

    def _diagnose(self):
        now = self._now()
        values = dict(self._counts, pressure_pa=self._ctl.pressure, target_nm=self._ctl.target,
                      last_reason=self._last_reason, friction_scale=self._ctl.friction_scale,
                      caution=self._ctl.caution, trim=self._ctl.trim, **self._peers.ages(now))
        stale = self._stale_reason(now)
        if stale:
            return "WARN", f"fail-safe 0 Pa: {stale}", values
        return "OK", "controlling", values


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros controller``."""
    return run_node(NAME, __doc__, PARAMS, ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
