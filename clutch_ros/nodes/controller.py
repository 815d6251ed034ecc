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

Wake-ups (the CPU of a node at these rates is mostly its executor's wake-ups, ~0.3-0.5 ms
each): with the ``timer`` trigger the step runs on a thread of its own
(:class:`~clutch_ros.nodes.cycle.Cycle`; a ROS timer with ``use_sim_time``) and takes its
three inputs itself (:class:`~clutch_ros.nodes.polled.PolledSubscription`, subscriptions no
executor waits on: the requests in arrival order, then the newest ``rig_state`` and
estimate), so the executor wakes only for parameters and diagnostics, not ~400 times a
second. The step sees every estimate that arrived before it (it used to see those whose
callback the executor had run before the timer). Arrival times are the middleware's
reception times (ROS time without ``use_sim_time``; with it, the step's time). With the
``estimate`` trigger requests and estimates are callbacks as before, and ``rig_state``
(whose arrival alone counts) is taken at each step and fail-safe check.

Parameters: every ``controller.*`` setting and every model key applies live (the next tick)
after validation: ranges by ROS, ``min_pressure <= max_pressure`` and the model's rules here;
a refused change names its reason and changes nothing.
"""

from __future__ import annotations

import threading

from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from clutch_ros.config.presets import default_preset
from clutch_ros.errors import ClutchError
from clutch_ros.interfaces import (
    CLUTCH_ESTIMATE,
    PRESSURE_COMMAND,
    RIG_STATE,
    TORQUE_REQUEST,
    stamp_to_s,
)
from clutch_ros.model.control import TorqueController
from clutch_ros.nodes.controller_params import (
    PARAMS,
    TIMEOUTS,
    TRIGGERS,
    WATCHDOG_FRACTION,
    controller_settings,
)
from clutch_ros.nodes.convert import CdrCodec
from clutch_ros.nodes.cycle import Cycle
from clutch_ros.nodes.diagnostics import Diagnostics, LogThrottle
from clutch_ros.nodes.model_params import apply_model_changes, declare_model_params
from clutch_ros.nodes.parameters import declare_params
from clutch_ros.nodes.peers import Input, PeerWatch
from clutch_ros.nodes.polled import PolledSubscription, Taken
from clutch_ros.nodes.qos import publisher_qos, sensor_qos, subscriber_qos
from clutch_ros.nodes.runner import run_node
from clutch_ros.nodes.stamps import stamp_to_sec

NAME = "controller"
#: PressureCommand's leaves in CDR order, as the controller's encoder writes them
_COMMAND_FIELDS = ("header.stamp.sec", "header.stamp.nanosec", "header.frame_id", "pressure",
                   "requested_torque", "predicted_torque", "limited", "reason", "trim_pressure")


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
        # timer trigger: the inputs are taken by the step (module docstring), else callbacks
        request_qos = subscriber_qos(TORQUE_REQUEST.name, depth=5)
        self._requests = None if self._on_estimates else PolledSubscription(
            self, TorqueRequest, TORQUE_REQUEST.name, request_qos, raw=True)
        if self._on_estimates:
            self.create_subscription(TorqueRequest, TORQUE_REQUEST.name, self._on_request,
                                     request_qos)
        # raw: only the arrival of rig_state counts here; not deserialising it saves the
        # message construction (~30 fields) on every sample
        self._rig = PolledSubscription(self, RigState, RIG_STATE.name, sensor_qos(), raw=True)
        # (estimate trigger: every estimate is answered, so none may be dropped: the topic's
        # reliable subscriber profile; timer: the newest one at each step)
        self._estimates = None if self._on_estimates else PolledSubscription(
            self, ClutchEstimate, CLUTCH_ESTIMATE.name, sensor_qos(), raw=True)
        if self._on_estimates:
            self.create_subscription(ClutchEstimate, CLUTCH_ESTIMATE.name, self._on_estimate,
                                     subscriber_qos(CLUTCH_ESTIMATE.name))
        # PressureCommand's fields in CDR order (header.stamp.sec, .nanosec, .frame_id,
        # pressure, requested_torque, predicted_torque, limited, reason, trim_pressure)
        codec = CdrCodec(PressureCommand)
        if codec.names != _COMMAND_FIELDS:
            raise ClutchError(f"PressureCommand fields {codec.names} changed")
        self._encode_cmd = codec.encode
        # the node clock's C handle: node time (ROS time, /clock with use_sim_time) without a
        # rclpy Time object per call
        self._clock_handle = self.get_clock().handle
        # use_sim_time: node time is never earlier than the newest request or estimate stamp
        # (a message stamped T proves that /clock reached T, whether or not this node's /clock
        # arrived first: the same time on every lock-step run, as the bridge's node time)
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        self._time_floor = 0.0  # [s]
        # the step (on the cycle thread with the timer trigger on wall-clock time) against
        # parameter changes and diagnostics (the executor)
        self._lock, self._cycle, self._cycle_warn = threading.Lock(), None, LogThrottle(5.0)
        self._timer = self._make_timer()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)

    def _on_set_parameters(self, params):
        with self._lock:
            return self._set_parameters(params)

    def _set_parameters(self, params):
        """Validate and apply controller.* and model keys at once (all or nothing).

        ROS checks each value against its descriptor's range first; here the set as a whole
        is checked (``min_pressure <= max_pressure``, the model's own rules). Accepted
        settings apply from the next tick: a lower ``max_pressure`` also clamps the pressure
        held now, so no later command exceeds it; a new ``rate`` applies from the next step.
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
            if self._cycle is not None:
                self._cycle.set_period("step", settings.period)
            elif period_changed or self._on_estimates:  # (the watchdog's follows timeouts)
                self.destroy_timer(self._timer)
                self._timer = self._make_timer()
            self.get_logger().info("controller settings changed: " + ", ".join(
                f"{k}={v}" for k, v in sorted(own.items())))
        return SetParametersResult(successful=True)

    def _make_timer(self):
        """Return the step's ROS timer, or start the cycle thread (timer trigger, wall clock)."""
        if self._on_estimates:
            return self.create_timer(self._watchdog_period(), self._watchdog)
        if self._sim_time:  # only a ROS timer follows /clock
            return self.create_timer(self._ctl.settings.period, self._tick)
        self._cycle = Cycle("controller_step", {"step": (self._ctl.settings.period, self._tick)},
                            self._on_cycle_error).start()
        return None

    def _on_cycle_error(self, job: str, err: BaseException) -> None:
        if self.context.ok() and self._cycle_warn.ready():  # (a shutdown ends the context)
            self.get_logger().error(f"{job}: {type(err).__name__}: {err}")

    def _watchdog_period(self) -> float:
        return WATCHDOG_FRACTION * min(self._cfg[key] for key in TIMEOUTS.values())

    def _now(self) -> float:
        now = self._clock_handle.get_now().nanoseconds * 1e-9
        return max(now, self._time_floor) if self._sim_time else now

    def _saw(self, stamp: float) -> None:
        if self._sim_time and stamp > self._time_floor:
            self._time_floor = stamp

    def destroy_node(self) -> None:
        """Stop the step, free the polled subscriptions, then the node."""
        if self._cycle is not None:
            self._cycle.stop()
        for sub in (self._requests, self._rig, self._estimates):
            if sub is not None:
                sub.destroy()
        super().destroy_node()

    def _arrival(self, item: Taken) -> float:
        """Node time [s] a polled message arrived: its reception time, the step's at worst."""
        now = self._now()
        if self._sim_time or item.received is None or abs(now - item.received) > 3600.0:
            return now  # (simulated time, no reception time, or another clock's)
        return min(item.received, now)

    def _poll(self) -> None:
        """Timer trigger: take the inputs that arrived since the last step (module docstring)."""
        assert self._requests is not None and self._estimates is not None  # (timer trigger)
        for item in self._requests.take():  # (the fields read from the bytes: view())
            req = self._requests.view(item.message)
            self._request(stamp_to_s(req.header_stamp_sec, req.header_stamp_nanosec),
                          req.torque, item)
        self._poll_rig()
        newest = self._estimates.take_newest()
        if newest is not None:
            est = self._estimates.view(newest.message)
            self._estimate_in(est, est.header_stamp_sec * 10**9 + est.header_stamp_nanosec,
                              newest)

    def _poll_rig(self) -> None:
        newest = self._rig.take_newest()
        if newest is not None:
            self._peers.seen("rig data", self._arrival(newest))

    def _on_request(self, msg) -> None:
        self._request(stamp_to_sec(msg.header.stamp), msg.torque)

    def _request(self, stamp: float, torque: float, polled: Taken | None = None) -> None:
        self._saw(stamp)
        now = self._now() if polled is None else self._arrival(polled)
        self._peers.seen("torque request", now)
        warning = self._ctl.set_request(now, torque, stamp if stamp > 0.0 else None)
        if warning:
            self._counts["bad_requests"] += 1
            if self._warn.ready():
                self.get_logger().warning(warning)

    def _on_estimate(self, msg) -> None:
        self._estimate_in(msg, msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

    def _estimate_in(self, msg, ns: int, polled: Taken | None = None) -> None:
        """Take an estimate stamped ``ns`` [ns]: a message, or a polled one's fields (view())."""
        self._estimate = msg
        self._saw(ns * 1e-9)
        now = self._now() if polled is None else self._arrival(polled)
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
        self._poll_rig()
        return self._peers.silent(now)

    def _tick(self) -> None:
        with self._lock:
            self._poll()
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
        # as Time.to_msg(): seconds and nanoseconds (node clock or the answered estimate's)
        sec, nanosec = divmod(stamp_ns, 10**9)
        self._counts["commands"] += 1
        self._counts["limited"] += out.limited
        self._last_reason = out.reason
        # the PressureCommand's CDR bytes, written without a message object (~40 us less)
        self._pub.publish(self._encode_cmd(
            sec, nanosec, "", float(out.pressure), float(out.requested_torque),
            float(out.predicted_torque), bool(out.limited), out.reason,
            float(out.trim_pressure)))

    def _diagnose(self):
        with self._lock:
            return self._status()

    def _status(self):
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
