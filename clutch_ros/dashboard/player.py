"""Bag playback onto the dashboard server in real time (× rate), under the clients' control.

:class:`BagPlayer` takes a :class:`~clutch_ros.dashboard.bag_stream.BagStream` and hands each
message to a :class:`~clutch_ros.dashboard.server.DashboardServer` when its bag time comes
due on the :class:`~clutch_ros.dashboard.playback.PlaybackClock`: at ``rate`` × real time, a
message recorded ``t`` seconds after the position playback (re)started goes out ``t / rate``
seconds after it. Messages keep their recorded bag time as log time, the header stamps inside
the CDR are never touched, and the server's time (``time`` capability) is the bag time, sent
every ``time_period_s`` while playing. Clients pause, resume, seek and change the speed
(playback control); a seek restarts the bag's stream at the new position, so a message and
its estimate go out exactly as at that position of a pass from the start. At the end the
player reports ``ended`` and waits for a seek (or returns with ``exit_at_end``); ``loop=True``
seeks back to the start instead, so log times repeat, each pass announced as a seek.

Once per ``diag_period_s`` of wall time the player publishes a ``DiagnosticArray`` on
``/diagnostics`` (serialized with the package's rosbags typestore) holding the server's
status (clients, subscriptions, forwarded messages, slow-client overflows; see
:meth:`~clutch_ros.dashboard.server.DashboardServer.status`) and its own figures: messages
published, bag position [s], rate, how late the last message went out [s]; none while
paused.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from typing import Any

from clutch_ros.bag.typestore import clutch_typestore, make_msg
from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.playback import PlaybackClock
from clutch_ros.dashboard.server import DashboardServer
from clutch_ros.dashboard.topics import DIAGNOSTIC_ARRAY

__all__ = ["BagPlayer", "diagnostic_array_cdr"]

_LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


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
    """Play a bag stream onto a dashboard server in real time × ``rate``, under control.

    Args:
        stream: the messages (a :class:`~clutch_ros.dashboard.bag_stream.BagStream`).
        server: where to publish (created with ``playback=clock`` for playback control).
        rate: playback speed, a factor of real time (0 < rate <= 1000); used when no
            ``clock`` is given.
        loop: start over at the end until stopped.
        diag_period_s: wall time between the player's ``/diagnostics`` messages [s].
        diag_topic: topic of those messages (must be served).
        clock: the :class:`~clutch_ros.dashboard.playback.PlaybackClock` clients control
            (default: a new one at ``rate``).
        time_period_s: wall time between the server's time messages while playing [s].
        exit_at_end: return at the end of the bag instead of waiting for a seek.

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
        clock: PlaybackClock | None = None,
        time_period_s: float = 0.05,
        exit_at_end: bool = True,
    ):
        if clock is None:
            clock = PlaybackClock(stream.start_ns, stream.end_ns, rate)
        if diag_topic not in server.channels:
            raise DashboardError(f"diagnostics topic {diag_topic} is not served")
        self.stream = stream
        self.server = server
        self.clock = clock
        self.loop = bool(loop)
        self.exit_at_end = bool(exit_at_end)
        self.diag_period_s = float(diag_period_s)
        self.time_period_s = float(time_period_s)
        self.diag_topic = diag_topic
        self.published = 0
        self.loops = 0
        self.seeks = 0
        self.lag_s = 0.0
        self.max_lag_s = 0.0
        self.position_s = 0.0
        self._next_diag = 0.0
        self._next_time = 0.0

    @property
    def rate(self) -> float:
        """The playback speed now [× real time]."""
        return self.clock.speed

    def stop(self) -> None:
        """Ask :meth:`run` to return (from another thread or a signal handler)."""
        self.clock.stop()

    def run(self) -> dict[str, Any]:
        """Play until stopped (or the end, with ``exit_at_end`` and no ``loop``); summarize.

        Summary: ``published`` [messages], ``loops`` (passes that reached the end), ``seeks``
        (by clients), ``position_s`` (bag time reached in the current pass) and
        ``max_lag_s`` (latest a message went out behind its schedule) [s], ``stopped`` (True
        when stopped before the end).
        """
        clock = self.clock
        self._next_diag = self._next_time = time.monotonic()
        start: int | None = clock.start_ns
        ended = False
        while not clock.stopped:
            outcome = self._play_from(clock.now_ns() if start is None else start)
            if outcome == "stop":
                break
            if outcome == "seek":
                self.seeks += 1
                start = clock.take_seek()
                continue
            self.loops += 1
            if self.loop:
                self.server.broadcast_playback(clock.seek(clock.start_ns))
                start = clock.take_seek()
                continue
            self.server.broadcast_playback(clock.mark_ended())
            self._diagnose(clock.end_ns)
            if self.exit_at_end:
                ended = True
                break
            with clock.changed:
                while not clock.stopped and not clock.seek_pending():
                    clock.changed.wait()
            self.seeks += not clock.stopped
            start = clock.take_seek()
        return {
            "published": self.published,
            "loops": self.loops,
            "seeks": self.seeks,
            "position_s": self.position_s,
            "max_lag_s": self.max_lag_s,
            "stopped": not ended,
        }

    def _play_from(self, start_ns: int) -> str:
        """Play from bag time ``start_ns`` until the end, a seek or a stop; return which."""
        clock = self.clock
        messages: Iterator[tuple[int, str, bytes]] = self.stream.messages(start_ns)
        first = next(messages, None)  # opens the bag: not part of the schedule
        if first is None:
            return "end"
        clock.start_at(start_ns)
        publish = self.server.publish
        for time_ns, topic, data in itertools.chain([first], messages):
            while True:
                with clock.changed:
                    if clock.stopped:
                        return "stop"
                    if clock.seek_pending():
                        return "seek"
                    due = clock.due_wall(time_ns)
                    now = time.monotonic()
                    if due is not None and now >= due:
                        break
                    if due is None:  # paused: sleep until a request
                        clock.changed.wait()
                        continue
                    wake = min(due, self._next_time, self._next_diag)
                    if wake > now:
                        clock.changed.wait(wake - now)
                        continue
                self._periodic(time_ns)
            self.lag_s = now - due
            self.max_lag_s = max(self.max_lag_s, self.lag_s)
            self.position_s = (time_ns - clock.start_ns) * 1e-9
            publish(topic, data, time_ns)
            self.published += 1
            self._periodic(time_ns)
        return "end"

    def _periodic(self, next_ns: int) -> None:
        """Send the time and ``/diagnostics`` when due (never past ``next_ns``, not sent)."""
        now = time.monotonic()
        if now >= self._next_time:
            self._next_time = now + self.time_period_s
            self.server.broadcast_time(min(self.clock.now_ns(), next_ns))
        if now >= self._next_diag:
            self._diagnose(min(self.clock.now_ns(), next_ns))

    def _diagnose(self, stamp_ns: int) -> None:
        self._next_diag = time.monotonic() + self.diag_period_s
        level, message, values = self.server.status()
        values.update(
            bag=str(self.stream.path),
            rate=self.rate,
            published=self.published,
            position_s=self.position_s,
            lag_s=self.lag_s,
            seeks=self.seeks,
            estimates_computed=bool(getattr(self.stream, "computed", False)),
        )
        data = diagnostic_array_cdr(stamp_ns, "/dashboard", level, message, values)
        self.server.publish(self.diag_topic, data, stamp_ns)
