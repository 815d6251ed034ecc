"""The demo's test-engineer stand-in: publishes torque requests and sets the rig motor speed.

``DemoDriver`` publishes ``torque_request`` at ``rate`` Hz following a profile
(:mod:`clutch_ros.rig.request_profile`), sets the simulated rig's slip speed (parameter
``rig.slip_speed`` of the ``rig_sim`` node, as a test engineer sets the rig motor) when the
profile's segment changes, and keeps the latest rig state, estimate and command for the
progress line. With ``on_clock`` (lock-step) it publishes one request per ``/clock`` value
instead, stamped with it (not on a timer of its own: every tick has its request).
"""

from __future__ import annotations

import math
from typing import Any

from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from clutch_ros.interfaces import CLUTCH_ESTIMATE, PRESSURE_COMMAND, RIG_STATE, TORQUE_REQUEST
from clutch_ros.nodes.qos import publisher_qos, sensor_qos, subscriber_qos
from clutch_ros.rig.request_profile import request_at, slip_at

__all__ = ["DemoDriver"]


class DemoDriver(Node):
    """Torque-request publisher and rig-speed setter for ``clutch demo``."""

    def __init__(self, profile, rate_hz: float = 50.0, rig_node: str = "rig_sim",
                 on_clock: bool = False):
        super().__init__("demo_driver")

        self.profile = profile
        self.duration = sum(seg.duration for seg in profile)
        self.started_at: float | None = None
        self.latest = {"rig": None, "estimate": None, "command": None}
        self.counts = {"rig": 0, "estimate": 0, "command": 0, "request": 0}
        self._slip_set: float | None = None
        self._slip_future: Future[Any] | None = None
        self._params = AsyncParameterClient(self, rig_node)
        self._pub = self.create_publisher(TorqueRequest, TORQUE_REQUEST.name,
                                          publisher_qos(TORQUE_REQUEST.name))
        self.create_subscription(RigState, RIG_STATE.name, self._keep("rig"), sensor_qos())
        self.create_subscription(ClutchEstimate, CLUTCH_ESTIMATE.name, self._keep("estimate"),
                                 subscriber_qos(CLUTCH_ESTIMATE.name))
        self.create_subscription(PressureCommand, PRESSURE_COMMAND.name, self._keep("command"),
                                 subscriber_qos(PRESSURE_COMMAND.name))
        self._clock_ns = -1  # on_clock: the newest /clock value [ns]
        if on_clock:
            self.create_subscription(Clock, "/clock", self._on_clock, 10)
        else:
            self.create_timer(1.0 / rate_hz, self._tick)

    def _on_clock(self, msg) -> None:
        ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if ns > self._clock_ns:  # (the rig publishes a tick again while it waits)
            self._clock_ns = ns
            self._tick(msg.clock)

    def _keep(self, key: str):
        def store(msg) -> None:
            self.latest[key] = msg
            self.counts[key] += 1
        return store

    def now(self) -> float:
        """Node clock time [s]."""
        return self.get_clock().now().nanoseconds * 1e-9

    def start(self) -> None:
        """Start the profile now."""
        self.started_at = self.now()

    def elapsed(self) -> float:
        """Seconds since :meth:`start` (0 before)."""
        return 0.0 if self.started_at is None else self.now() - self.started_at

    @property
    def finished(self) -> bool:
        """True once the profile has run to its end."""
        return self.started_at is not None and self.elapsed() >= self.duration

    def set_slip_speed(self, slip_speed: float) -> None:
        """Ask the rig to hold ``slip_speed`` [rad/s] (asynchronous parameter call)."""
        if self._slip_set == slip_speed:
            return
        if not self._params.services_are_ready():
            return
        self._slip_set = slip_speed
        self._slip_future = self._params.set_parameters(
            [Parameter("rig.slip_speed", value=float(slip_speed))])

    def _tick(self, stamp=None) -> None:
        """Publish the request of now (``stamp``: of that time, a ``/clock`` value)."""
        t = self.elapsed()
        if stamp is not None and self.started_at is not None:
            t = stamp.sec + stamp.nanosec * 1e-9 - self.started_at
        self.set_slip_speed(slip_at(self.profile, t))
        if self.started_at is None:
            return
        msg = TorqueRequest()
        msg.header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        msg.torque = float(request_at(self.profile, t)) if t < self.duration else 0.0
        self._pub.publish(msg)
        self.counts["request"] += 1

    def progress_line(self) -> str:
        """One human line: time, request, measured, modelled torque, command."""
        rig, est, cmd = self.latest["rig"], self.latest["estimate"], self.latest["command"]
        t = self.elapsed()

        def fmt(value):
            return "   -  " if value is None or not math.isfinite(value) else f"{value:6.0f}"
        return (f"[{t:5.1f}/{self.duration:.1f} s] request {fmt(request_at(self.profile, t))} "
                f"N m | measured {fmt(rig.measured_torque if rig else None)} | modelled "
                f"{fmt(est.modelled_torque if est else None)} | pressure "
                f"{fmt(cmd.pressure / 1e5 if cmd else None)} bar | mu x "
                f"{est.friction_scale if est else math.nan:.3f}")
