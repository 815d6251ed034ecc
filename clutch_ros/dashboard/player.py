"""Bag playback onto the dashboard server in real time (× rate), with its own diagnostics.

:class:`BagPlayer` takes a :class:`~clutch_ros.dashboard.bag_stream.BagStream` and hands each
message to a :class:`~clutch_ros.dashboard.server.DashboardServer` when its bag time comes
due on the wall clock: a message recorded ``t`` seconds after the bag's start goes out
``t / rate`` seconds after playback started. Messages keep their recorded bag time as log
time (each further loop of ``loop=True`` adds one bag length plus one period, so log time
only moves forward); the header stamps inside the CDR are never touched.

Once per ``diag_period_s`` of wall time the player publishes a ``DiagnosticArray`` on
``/diagnostics`` (serialized with the package's rosbags typestore) holding the server's
status (clients, subscriptions, forwarded messages, slow-client overflows; see
:meth:`~clutch_ros.dashboard.server.DashboardServer.status`) and its own figures: messages
published, bag position [s], rate, how late the last message went out [s].
"""

from __future__ import annotations

import itertools
import threading
import time
from typing import Any

from clutch_ros.bag.typestore import clutch_typestore, make_msg
from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.server import DashboardServer
from clutch_ros.dashboard.topics import DIAGNOSTIC_ARRAY

__all__ = ["BagPlayer", "diagnostic_array_cdr"]

_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}
_MAX_RATE = 1000.0


def _fmt(value: Any) -> str:
    """Render a diagnostic value as ROS tools do (floats with 6 significant digits)."""
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def diagnostic_array_cdr(
    stamp_ns: int, name: str, level: str, message: str, values: dict[str, Any]
) -> bytes:
    """Serialize a one-status ``diagnostic_msgs/DiagnosticArray`` to CDR bytes.

    Args:
        stamp_ns: header stamp [ns since epoch].
        name: status name (``/dashboard``); also its hardware id.
        level: ``OK``, ``WARN``, ``ERROR`` or ``STALE``.
        message: one-line summary.
        values: key/value pairs (rendered as strings).

    """
    store = clutch_typestore()
    pairs = [
        make_msg("diagnostic_msgs/msg/KeyValue", key=str(k), value=_fmt(v))
        for k, v in values.items()
    ]
    status = make_msg(
        "diagnostic_msgs/msg/DiagnosticStatus",
        level=_LEVELS[level],
        name=name,
        message=message,
        hardware_id=name.strip("/"),
        values=pairs,
    )
    array = make_msg(DIAGNOSTIC_ARRAY, stamp_ns, status=[status])
    return bytes(store.serialize_cdr(array, DIAGNOSTIC_ARRAY))


class BagPlayer:
    """Play a bag stream onto a dashboard server in real time × ``rate``.

    Args:
        stream: the messages (a :class:`~clutch_ros.dashboard.bag_stream.BagStream`).
        server: where to publish.
        rate: playback speed, a factor of real time (0 < rate <= 1000).
        loop: start over at the end until stopped.
        diag_period_s: wall time between the player's ``/diagnostics`` messages [s].
        diag_topic: topic of those messages (must be served).

    Raises:
        DashboardError: ``rate`` out of range, or ``diag_topic`` not served.

    """

    def __init__(
        self,
        stream: Any,
        server: DashboardServer,
        *,
        rate: float = 1.0,
        loop: bool = False,
        diag_period_s: float = 1.0,
        diag_topic: str = "/diagnostics",
    ):
        if not 0.0 < float(rate) <= _MAX_RATE:
            raise DashboardError(f"playback rate {rate} must be in (0, {_MAX_RATE:g}]")
        if diag_topic not in server.channels:
            raise DashboardError(f"diagnostics topic {diag_topic} is not served")
        self.stream = stream
        self.server = server
        self.rate = float(rate)
        self.loop = bool(loop)
        self.diag_period_s = float(diag_period_s)
        self.diag_topic = diag_topic
        self.published = 0
        self.loops = 0
        self.lag_s = 0.0
        self.max_lag_s = 0.0
        self.position_s = 0.0
        self._stop = threading.Event()
        self._next_diag = 0.0
        self._offset_ns = 0

    def stop(self) -> None:
        """Ask :meth:`run` to return (from another thread or a signal handler)."""
        self._stop.set()

    def run(self) -> dict[str, Any]:
        """Play until the end (or forever with ``loop``) or :meth:`stop`; return a summary.

        Summary: ``published`` [messages], ``loops`` (complete passes), ``position_s`` (bag
        time reached in the current pass) and ``max_lag_s`` (latest a message went out
        behind its schedule) [s], ``stopped`` (True when stopped early).
        """
        length_ns = max(0, self.stream.end_ns - self.stream.start_ns) + int(
            self.diag_period_s * 1e9
        )
        self._next_diag = time.monotonic()
        while not self._stop.is_set():
            self._play_once()
            if self._stop.is_set():
                break
            self.loops += 1
            if not self.loop:
                self._diagnose(self.stream.end_ns + self._offset_ns)
                break
            self._offset_ns += length_ns
        return {
            "published": self.published,
            "loops": self.loops,
            "position_s": self.position_s,
            "max_lag_s": self.max_lag_s,
            "stopped": self._stop.is_set(),
        }

    def _play_once(self) -> None:
        start_ns = self.stream.start_ns
        scale = 1e-9 / self.rate
        publish = self.server.publish
        messages = iter(self.stream)
        first = next(messages, None)  # opens the bag: not part of the schedule
        if first is None:
            return
        wall0 = time.monotonic()
        for time_ns, topic, data in itertools.chain([first], messages):
            due = wall0 + (time_ns - start_ns) * scale
            now = time.monotonic()
            while now < due:
                if now >= self._next_diag:
                    self._diagnose(time_ns + self._offset_ns)
                if self._stop.wait(min(due, self._next_diag) - now):
                    return
                now = time.monotonic()
            self.lag_s = now - due
            self.max_lag_s = max(self.max_lag_s, self.lag_s)
            self.position_s = (time_ns - start_ns) * 1e-9
            publish(topic, data, time_ns + self._offset_ns)
            self.published += 1
            if now >= self._next_diag:
                self._diagnose(time_ns + self._offset_ns)

    def _diagnose(self, stamp_ns: int) -> None:
        self._next_diag = time.monotonic() + self.diag_period_s
        level, message, values = self.server.status()
        values.update(
            bag=str(self.stream.path),
            rate=self.rate,
            published=self.published,
            position_s=self.position_s,
            lag_s=self.lag_s,
            estimates_computed=bool(getattr(self.stream, "computed", False)),
        )
        data = diagnostic_array_cdr(stamp_ns, "/dashboard", level, message, values)
        self.server.publish(self.diag_topic, data, stamp_ns)
