"""The bag player's clock under client control: play, pause, seek, speed (thread safe).

:class:`PlaybackClock` maps bag time to wall time: ``bag = anchor_bag + (wall - anchor_wall)
× speed`` while playing, a frozen ``anchor_bag`` while paused or at the end. A client's
playback-control request (on an SDK thread, :meth:`PlaybackClock.request`) re-anchors the
clock at the current bag time, so a pause holds the position and a speed change takes effect
from now; a seek records the new position for the player thread (:meth:`take_seek`) and wakes
it (the player waits on :attr:`PlaybackClock.changed`).
"""

from __future__ import annotations

import threading
import time

from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.sdk_listener import PlaybackReport

__all__ = ["MAX_SPEED", "PlaybackClock", "check_speed"]

#: Fastest playback [× real time].
MAX_SPEED = 1000.0


def check_speed(speed: float) -> float:
    """Return ``speed`` as a float if it is in (0, :data:`MAX_SPEED`], else raise."""
    speed = float(speed)
    if not 0.0 < speed <= MAX_SPEED:
        raise DashboardError(f"playback rate {speed} must be in (0, {MAX_SPEED:g}]")
    return speed


class PlaybackClock:
    """Bag time as a function of wall time, changed by clients.

    Args:
        start_ns, end_ns: the bag's first and last time [ns since epoch].
        speed: initial speed [× real time].
        clock: monotonic clock [s] (tests may pass their own).

    Attributes:
        changed: a :class:`threading.Condition` notified on every request and :meth:`stop`.
        stopped: True once :meth:`stop` was called.

    """

    def __init__(self, start_ns: int, end_ns: int, speed: float = 1.0, clock=time.monotonic):
        self.start_ns, self.end_ns = int(start_ns), int(end_ns)
        self.speed = check_speed(speed)
        self._clock = clock
        self.changed = threading.Condition()
        self.stopped = False
        self.playing = True
        self.ended = False
        self._seek: int | None = None
        self._anchor_bag = self.start_ns
        self._anchor_wall = clock()

    # -- reading (the player thread holds ``changed`` or not; values are consistent) ---------
    def now_ns(self) -> int:
        """Return the bag time now [ns since epoch]."""
        with self.changed:
            return self._now_locked()

    def _now_locked(self) -> int:
        if not self.playing or self.ended:
            return self._anchor_bag
        elapsed = (self._clock() - self._anchor_wall) * self.speed
        return self._anchor_bag + int(elapsed * 1e9)

    def due_wall(self, bag_ns: int) -> float | None:
        """Return the wall time [s, monotonic] ``bag_ns`` is due at (None: paused)."""
        if not self.playing or self.ended:
            return None
        return self._anchor_wall + (bag_ns - self._anchor_bag) * 1e-9 / self.speed

    def report(self, did_seek: bool = False) -> PlaybackReport:
        """Return the state now, for a ``playbackState`` message."""
        with self.changed:
            return self._report_locked(did_seek)

    def _report_locked(self, did_seek: bool) -> PlaybackReport:
        status = "ended" if self.ended else "playing" if self.playing else "paused"
        return PlaybackReport(status, min(self._now_locked(), self.end_ns), self.speed, did_seek)

    # -- changes ------------------------------------------------------------------------------
    def request(self, play: bool, speed: float, seek_ns: int | None) -> PlaybackReport:
        """Apply a client's playback-control request; return the state it leads to.

        A speed outside (0, :data:`MAX_SPEED`] keeps the current speed. A seek is clamped to
        the bag; it also leaves the end.
        """
        with self.changed:
            current = self._now_locked()
            if 0.0 < speed <= MAX_SPEED:
                self.speed = float(speed)
            did_seek = seek_ns is not None
            if seek_ns is not None:
                current = min(max(int(seek_ns), self.start_ns), self.end_ns)
                self._seek = current
                self.ended = False
            self.playing = bool(play)
            self._anchor_bag, self._anchor_wall = current, self._clock()
            self.changed.notify_all()
            status = "ended" if self.ended else "playing" if self.playing else "paused"
            return PlaybackReport(status, min(current, self.end_ns), self.speed, did_seek)

    def seek(self, bag_ns: int) -> PlaybackReport:
        """Seek to ``bag_ns`` keeping play/pause and speed (the player's own loop)."""
        with self.changed:
            playing = self.playing
        return self.request(playing, self.speed, bag_ns)

    def take_seek(self) -> int | None:
        """Return and clear a pending seek position [ns since epoch]."""
        with self.changed:
            seek, self._seek = self._seek, None
            return seek

    def seek_pending(self) -> bool:
        """Return True when a seek waits to be taken."""
        return self._seek is not None

    def start_at(self, bag_ns: int) -> None:
        """Anchor the schedule: bag time ``bag_ns`` is now (after opening the bag)."""
        with self.changed:
            self._anchor_bag, self._anchor_wall = int(bag_ns), self._clock()

    def mark_ended(self) -> PlaybackReport:
        """Hold the clock at the end: the end of the bag was reached."""
        with self.changed:
            self._anchor_bag = self.end_ns
            self.ended = True
            self.changed.notify_all()
            return self._report_locked(False)

    def stop(self) -> None:
        """Stop: every waiter wakes up."""
        with self.changed:
            self.stopped = True
            self.changed.notify_all()
