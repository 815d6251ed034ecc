"""A node's health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray), and log throttling."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from clutch_ros.nodes.parameters import HARDWARE_ID_PARAM

__all__ = ["Diagnostics", "LogThrottle"]


class Diagnostics:
    """Publish one DiagnosticStatus of this node on ``/diagnostics`` about once per period.

    ``collect`` is called on each tick and returns ``(level, message, values)`` with level one
    of ``"OK"``, ``"WARN"``, ``"ERROR"``, ``"STALE"`` and values a flat mapping (rendered as
    strings).
    """

    def __init__(self, node, collect: Callable[[], tuple[str, str, dict]], period_s: float = 1.0,
                 hardware_id: str = "", suffix: str = ""):
        """Publish ``collect()`` every ``period_s`` [s].

        The status is named after the node (``/ns/node``); ``suffix`` (``/realtime``) names
        a second status of the same node beside its main one.

        ``hardware_id`` names the hardware the status is about (the CAN interface and
        channel, or ``simulated rig``); empty: the node's ``diagnostics.hardware_id``
        parameter when declared (:data:`HARDWARE_ID_PARAM`), else the node name.
        """
        self._node = node
        if not hardware_id and node.has_parameter(HARDWARE_ID_PARAM.name):
            hardware_id = node.get_parameter(HARDWARE_ID_PARAM.name).value
        self.hardware_id = hardware_id or node.get_name()
        self._collect = collect
        self._suffix = suffix
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish_now)

    def publish_now(self) -> None:
        """Collect and publish one status now."""
        level, message, values = self._collect()
        status = DiagnosticStatus()
        status.level = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN,
                        "ERROR": DiagnosticStatus.ERROR,
                        "STALE": DiagnosticStatus.STALE}[level]
        status.name = (f"{self._node.get_namespace().rstrip('/')}/{self._node.get_name()}"
                       f"{self._suffix}")
        status.message = message
        status.hardware_id = self.hardware_id
        status.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [status]
        self._pub.publish(array)


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


class LogThrottle:
    """Let a log call through at most once per ``period_s`` (monotonic clock).

    Use instead of rclpy's ``throttle_duration_sec``: rclpy inspects the caller's source file
    on every call, throttled or not (about 1 ms), which stalls a node exactly when it is
    busiest (a burst of bad samples).
    """

    def __init__(self, period_s: float = 5.0):
        self.period_s = period_s
        self._last = -math.inf

    def ready(self) -> bool:
        """Return True (and start a new period) when a message may be logged now."""
        now = time.monotonic()
        if now - self._last >= self.period_s:
            self._last = now
            return True
        return False
