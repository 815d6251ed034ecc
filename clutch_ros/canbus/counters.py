"""Frame counters, per-identifier rates, a rate limiter for reports, a RigState pacer.

Memory stays bounded whatever the bus carries: per-identifier counts are kept for the frames
of the DBC only, and unknown identifiers in a table of at most :data:`UNKNOWN_ID_CAPACITY`
distinct keys (exact counts for the keys in it; frames of further keys are summed in
``unknown_untracked``).

Nothing here takes a lock: :class:`FrameCounters` is updated under the lock of its owner
(:class:`clutch_ros.canbus.assembler.RigStateAssembler`). Times are seconds in whatever base
the caller passes (bus time or a monotonic clock), never read from the system clock here.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any

from clutch_ros.canbus.dbc import format_frame_key

__all__ = [
    "UNKNOWN_ID_CAPACITY",
    "CounterSnapshot",
    "FrameCounters",
    "PublishPacer",
    "RateLimiter",
    "classify_socketcan_error",
]

#: Distinct unknown identifiers counted one by one; frames of further ones are summed.
UNKNOWN_ID_CAPACITY = 256

# SocketCAN error classes (linux/can/error.h), carried in the error frame's identifier.
_CAN_ERR_CRTL = 0x00000004
_CAN_ERR_BUSOFF = 0x00000040
_CAN_ERR_CRTL_RX_OVERFLOW = 0x01
_CAN_ERR_CRTL_TX_OVERFLOW = 0x02


def classify_socketcan_error(arbitration_id: int, data: bytes | bytearray) -> tuple[bool, bool]:
    """Return ``(bus_off, controller_overflow)`` for a SocketCAN-style error frame.

    SocketCAN puts the error class into the identifier (``CAN_ERR_BUSOFF`` 0x40,
    ``CAN_ERR_CRTL`` 0x04 with RX/TX overflow flags in byte 1). Other interfaces report error
    frames with identifier 0, which classifies as neither.
    """
    bus_off = bool(arbitration_id & _CAN_ERR_BUSOFF)
    overflow = bool(
        arbitration_id & _CAN_ERR_CRTL
        and len(data) > 1
        and data[1] & (_CAN_ERR_CRTL_RX_OVERFLOW | _CAN_ERR_CRTL_TX_OVERFLOW)
    )
    return bus_off, overflow


@dataclass(frozen=True)
class CounterSnapshot:
    """A consistent copy of the frame counters (all counts are numbers of frames).

    Invariants: ``frames_total == error_frames + remote_frames + data_frames`` and
    ``data_frames == decoded_frames + unknown_frames + decode_errors``. ``fd_frames`` counts
    data and remote frames with the FD flag, whatever happened to them. ``dropped_frames``
    is the sum of rolling-counter gaps of counter-carrying frames (a 4-bit counter sees at most 15
    consecutive losses; a repeated counter is counted in ``counter_repeats`` instead).
    ``bus_off_frames`` and ``controller_overflows`` are only counted for SocketCAN-style error
    frames. ``per_id`` counts data and remote frames of the DBC's identifiers by frame key
    (:func:`clutch_ros.canbus.dbc.frame_key`); ``unknown_id_counts`` counts data frames not
    in the DBC for at most :data:`UNKNOWN_ID_CAPACITY` keys (the first seen), and
    ``unknown_untracked`` the unknown frames of any further key, so
    ``sum(unknown_id_counts.values()) + unknown_untracked == unknown_frames``.
    """

    frames_total: int = 0
    data_frames: int = 0
    decoded_frames: int = 0
    unknown_frames: int = 0
    decode_errors: int = 0
    decode_errors_by_reason: dict[str, int] = field(default_factory=dict)
    error_frames: int = 0
    bus_off_frames: int = 0
    controller_overflows: int = 0
    remote_frames: int = 0
    fd_frames: int = 0
    dropped_frames: int = 0
    counter_repeats: int = 0
    listener_errors: int = 0
    per_id: dict[int, int] = field(default_factory=dict)
    unknown_id_counts: dict[int, int] = field(default_factory=dict)
    unknown_untracked: int = 0

    @property
    def unknown_ids(self) -> frozenset[int]:
        """Keys of the unknown identifiers counted one by one."""
        return frozenset(self.unknown_id_counts)

    def unknown_ids_text(self, limit: int = 10) -> str:
        """Return the ``limit`` most frequent unknown identifiers and the rest summed.

        Form: ``0x123: 50, 0x18EBFF00x: 7, ... +12 IDs: 40 frames`` (most frequent first, ties
        by key); bounded whatever the bus carries.
        """
        top = sorted(self.unknown_id_counts.items(), key=lambda kv: (-kv[1], kv[0]))
        text = ", ".join(f"{format_frame_key(k)}: {n}" for k, n in top[:limit])
        rest_ids = len(top) - min(limit, len(top))
        rest_frames = self.unknown_frames - sum(n for _, n in top[:limit])
        if rest_frames:
            more = f"+{rest_ids}{'+' if self.unknown_untracked else ''} IDs: {rest_frames} frames"
            text = f"{text}, {more}" if text else more
        return text


class FrameCounters:
    """Mutable frame counters; the owner serialises access (see module docstring)."""

    def __init__(self) -> None:
        self.frames_total = 0
        self.data_frames = 0
        self.decoded_frames = 0
        self.unknown_frames = 0
        self.decode_errors: Counter[str] = Counter()
        self.error_frames = 0
        self.bus_off_frames = 0
        self.controller_overflows = 0
        self.remote_frames = 0
        self.fd_frames = 0
        self.dropped_frames = 0
        self.counter_repeats = 0
        self.listener_errors = 0
        self.per_id: Counter[int] = Counter()
        self.unknown_ids: dict[int, int] = {}
        self.unknown_untracked = 0
        self._rate_base: tuple[float, dict[int, int], int] | None = None

    def snapshot(self) -> CounterSnapshot:
        """Return an immutable copy of the counters."""
        return CounterSnapshot(
            frames_total=self.frames_total,
            data_frames=self.data_frames,
            decoded_frames=self.decoded_frames,
            unknown_frames=self.unknown_frames,
            decode_errors=sum(self.decode_errors.values()),
            decode_errors_by_reason=dict(self.decode_errors),
            error_frames=self.error_frames,
            bus_off_frames=self.bus_off_frames,
            controller_overflows=self.controller_overflows,
            remote_frames=self.remote_frames,
            fd_frames=self.fd_frames,
            dropped_frames=self.dropped_frames,
            counter_repeats=self.counter_repeats,
            listener_errors=self.listener_errors,
            per_id=dict(self.per_id),
            unknown_id_counts=dict(self.unknown_ids),
            unknown_untracked=self.unknown_untracked,
        )

    def count_unknown(self, key: int, n: int = 1) -> None:
        """Count ``n`` data frames whose frame ``key`` is not in the DBC (bounded memory)."""
        self.unknown_frames += n
        count = self.unknown_ids.get(key)
        if count is not None:
            self.unknown_ids[key] = count + n
        elif len(self.unknown_ids) < UNKNOWN_ID_CAPACITY:
            self.unknown_ids[key] = n
        else:
            self.unknown_untracked += n

    def rates(self, now: float) -> tuple[float, dict[int, float]]:
        """Return ``(total [frames/s], {frame key: frames/s})`` since the previous call.

        ``now`` [s] is any monotonic time. The first call only sets the reference and
        returns zeros. Meant for one caller (the 1 Hz diagnostics).
        """
        base = self._rate_base
        self._rate_base = (now, dict(self.per_id), self.frames_total)
        if base is None or now <= base[0]:
            return 0.0, {}
        then, counts, total = base
        dt = now - then
        per_id = {
            key: (count - counts.get(key, 0)) / dt
            for key, count in self.per_id.items()
            if count != counts.get(key, 0)
        }
        return (self.frames_total - total) / dt, per_id


class RateLimiter:
    """Let an event through at most once per ``interval`` [s]; count the ones held back.

    ``allow(now)`` returns True (and the number suppressed since the last allowed event via
    :attr:`suppressed_at_last_allow`) when at least ``interval`` seconds passed since the last
    allowed event. ``now`` is any monotonic time [s].
    """

    def __init__(self, interval: float) -> None:
        if not interval >= 0.0:
            raise ValueError(f"interval must be >= 0 s, got {interval!r}")
        self.interval = interval
        self._last: float | None = None
        self.suppressed = 0
        self.suppressed_at_last_allow = 0

    def allow(self, now: float) -> bool:
        """Return True when the event may be reported now, else count it as suppressed."""
        if self._last is None or now - self._last >= self.interval:
            self._last = now
            self.suppressed_at_last_allow = self.suppressed
            self.suppressed = 0
            return True
        self.suppressed += 1
        return False


class PublishPacer:
    """Decide when a RigState is published: event driven by frames, at most ``rate``.

    The frame with key ``trigger`` (the one that completes the rig's cycle, e.g. RigSpeed)
    publishes at once, so a RigState leaves with the frame's latency instead of waiting for a
    timer. A token bucket (``rate`` [1/s], bursts of ``burst``) caps the average rate without
    losing a sample to jitter when frames come exactly at ``rate``. While the trigger frame is
    missing, any frame in ``fallback`` publishes once rig frames have been arriving for
    ``2 / rate`` s without a trigger (counted from the first frame after the last publication
    attempt), so the topic degrades to half the rate instead of stopping. The count starts at
    a frame, not at the last attempt: after a pause of the whole bus (a stalled rig, a busy
    PC) the cycle's first frames are no "missing trigger" -- its trigger is still to come, and
    publishing before it would send a sample half of whose signals are a cycle old. The same
    holds for a pause within a cycle: a gap of more than ``1 / rate`` s between two rig frames
    is a pause, not frames flowing, so the count starts over at the frame after it. A frame
    held back by the cap leaves the pacer ``pending``: :meth:`flush`, called from a slow
    timer, publishes it once the cap allows, so the last state before the bus goes quiet is
    never withheld.
    ``trigger`` None: frames never publish and :meth:`flush` is the ``rate`` timer's
    decision. Times [s] are passed by the caller, in the bus's time base (the frames'
    timestamps), so a burst of frames read late is paced as the bus sent it; a time that
    goes back (a new log, an adapter's clock reset) earns no tokens. Not thread-safe.
    """

    def __init__(self, rate: float, trigger: int | None,
                 fallback: Collection[int] = frozenset(),
                 burst: float = 2.0) -> None:
        if not rate > 0.0:
            raise ValueError(f"rate must be > 0 1/s, got {rate!r}")
        self.rate, self.trigger, self.fallback, self.burst = rate, trigger, fallback, burst
        self._tokens = burst
        self._last: float | None = None
        # bus time [s] of the first rig frame since the last publication attempt: frames
        # flowing for 2 / rate s from here without a trigger mean the trigger is missing
        self._flowing_since: float | None = None
        self._last_frame: float | None = None  # bus time [s] of the last rig frame counted
        #: a frame was held back by the rate cap and not published since
        self.pending = False

    def on_frame(self, key: int, now: float) -> bool:
        """Return True when the frame with ``key`` arriving at ``now`` should publish."""
        if self.trigger is None:
            return False
        if key != self.trigger and not self.fallback_due(key, now):
            return False
        self._flowing_since = None
        allowed = self.take(now)
        self.pending = not allowed
        return allowed

    def fallback_due(self, key: int, now: float) -> bool:
        """Count the non-trigger frame ``key`` at ``now`` [s]; True when it is to publish.

        True when ``key`` is in ``fallback`` and rig frames have been flowing for more than
        ``2 / rate`` s without a trigger (class docstring); the publication itself is then
        :meth:`on_frame`'s decision. Calling it again with the same ``key`` and ``now``
        changes nothing and gives the same answer, so a caller may ask it first, without the
        lock a publication needs, and call :meth:`on_frame` only when it is True (the
        can_bridge does, for each of its ~2,400 rig frames/s).
        """
        if key not in self.fallback:
            return False
        last, self._last_frame = self._last_frame, now
        if (self._flowing_since is None or now < self._flowing_since
                or last is None or (now - last) * self.rate > 1.0):
            # (a time going back: a new log starts over; a pause: the trigger decides)
            self._flowing_since = now
        return (now - self._flowing_since) * self.rate > 2.0

    def trigger_held(self, now: float) -> bool:
        """:meth:`on_frame` for the trigger at ``now`` [s] when it declines; else nothing.

        True: the trigger frame is held back by the cap, with the state :meth:`on_frame`
        leaves then (tokens earned, ``pending``). False: nothing changed, and
        :meth:`on_frame` decides. The can_bridge asks it first for each trigger frame (up to
        1,000/s, of which ``rate`` publish), without the work a publication needs.
        """
        if self.trigger is None or self._earned(now) >= 1.0:
            return False
        self._tokens, self._last, self._flowing_since, self.pending = (
            self._earned(now), now, None, True)
        return True

    def _earned(self, now: float) -> float:
        """Return the tokens at ``now`` [s] (those left plus those accrued, at most ``burst``)."""
        if self._last is None:
            return self._tokens
        return min(self.burst, self._tokens + max(0.0, now - self._last) * self.rate)

    def flush(self, now: float) -> bool:
        """Timer decision at ``now``: publish a pending frame (or, without trigger, any)."""
        if self.trigger is not None and not (self.pending and self._last is not None
                                             and (now - self._last) * self.rate >= 1.0):
            return False
        allowed = self.take(now)
        self.pending = self.pending and not allowed
        return allowed

    def take(self, now: float) -> bool:
        """Return True (and use a token) when a publication is allowed at ``now``."""
        self._tokens, self._last = self._earned(now), now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True

    def refund(self) -> None:
        """Give back the token of an allowed publication that did not happen (nothing new)."""
        self._tokens = min(self.burst, self._tokens + 1.0)

    def export_state(self, out: Any) -> None:
        """Write the state into ``out[0:7]`` (the layout of compiled pacing code).

        Tokens, last, flowing since, last frame (NaN: None), pending, ``rate``, ``burst``;
        ``out``: a float array or list of at least 7.
        """
        nan = math.nan
        out[0], out[1], out[2], out[3], out[4], out[5], out[6] = (
            self._tokens, nan if self._last is None else self._last,
            nan if self._flowing_since is None else self._flowing_since,
            nan if self._last_frame is None else self._last_frame,
            1.0 if self.pending else 0.0, self.rate, self.burst)

    def import_state(self, state: Any) -> None:
        """Take the state :meth:`export_state` wrote (after compiled code changed it)."""
        tokens, last, flowing, last_frame, pending = (float(v) for v in state[:5])
        self._tokens = tokens
        self._last = None if math.isnan(last) else last
        self._flowing_since = None if math.isnan(flowing) else flowing
        self._last_frame = None if math.isnan(last_frame) else last_frame
        self.pending = pending != 0.0

    def until_allowed(self, now: float) -> float:
        """Return how long [s] after ``now`` the next publication can be allowed (0: at once).

        No publication, whatever the frame, is allowed earlier (each needs a token), so a
        receiver may leave the frames queued until then and read them in one batch.
        """
        if self._last is None:
            return 0.0
        tokens = self._tokens + max(0.0, now - self._last) * self.rate
        return 0.0 if tokens >= 1.0 else (1.0 - tokens) / self.rate
