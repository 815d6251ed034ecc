"""Bus configuration, opening, and a self-healing bus for bus-off and unplugged adapters.

:class:`BusConfig`, :func:`open_bus` and :func:`parse_filters` live in
:mod:`clutch_ros.canbus.config` and are re-exported here. :class:`ReconnectingBus` is a
:class:`can.BusABC` that wraps such a bus: when receiving or sending fails
(``CanOperationError``, ``OSError``, ...), the controller reports bus-off (``BusState.ERROR``
or a SocketCAN bus-off error frame) or the adapter cannot be opened, it closes the bus and
reopens it with exponential back-off. A received datagram or frame that is no valid CAN frame
(:func:`~clutch_ros.canbus.udp.malformed_reason`: not msgpack, an 11-bit identifier above
0x7FF, a DLC that differs from the data length, ...) is counted by reason and dropped; it
never takes the link down, since the transport itself is fine. It never raises from
:meth:`~can.BusABC.recv` (so a
:class:`can.Notifier` on it never dies), reports every state transition to a callback and
logs rate-limited (no warning storm).

Own frames: python-can's ``udp_multicast`` loops every sent frame back to the sender (the
socket joins the group it sends to), although it cannot honour ``receive_own_messages``.
:class:`ReconnectingBus` removes those echoes (:class:`EchoFilter`), so with
``receive_own_messages=False`` a node never decodes its own PumpRequests, whatever the
interface.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import can
import can.interfaces

from clutch_ros.canbus.batch import RawFrame, ReaderSlot, message_frame
from clutch_ros.canbus.config import BusConfig, open_bus, parse_filters
from clutch_ros.canbus.counters import RateLimiter, classify_socketcan_error
from clutch_ros.canbus.errors import BusConfigError, BusUnavailable
from clutch_ros.canbus.intake import Columns
from clutch_ros.canbus.udp import (
    ECHOING_INTERFACES,
    EchoFilter,
    malformed_reason,
    receive_drops,
    tune_udp_multicast,
)
from clutch_ros.canbus.udp_columns import ColumnReader, drop_echoes

__all__ = [
    "BusConfig",  # BusConfig, open_bus, parse_filters: re-exported from canbus.config
    "EchoFilter",  # EchoFilter, tune_udp_multicast: re-exported from canbus.udp
    "LinkEvent",
    "LinkState",
    "LinkStatus",
    "ReconnectingBus",
    "open_bus",
    "parse_filters",
    "tune_udp_multicast",
]

_LOG = logging.getLogger(__name__)


def _add(a: int | None, b: int | None) -> int | None:
    """Sum of two counts where None means unknown (unknown only when both are)."""
    return b if a is None else a if b is None else a + b


class LinkState(StrEnum):
    """State of a :class:`ReconnectingBus` link."""

    CONNECTING = "connecting"
    UP = "up"
    DOWN = "down"
    CLOSED = "closed"


@dataclass(frozen=True)
class LinkEvent:
    """A link state transition at ``time`` [s] (the bus's clock), with its reason."""

    time: float
    old: LinkState
    new: LinkState
    reason: str


@dataclass(frozen=True)
class LinkStatus:
    """Diagnostics of a :class:`ReconnectingBus` (times in seconds of its clock)."""

    state: LinkState
    reason: str
    since: float
    connects: int
    disconnects: int
    failed_attempts: int
    next_attempt_in: float
    send_failures: int
    bus_off_frames: int
    bus_state: str
    suppressed_reports: int
    own_echoes: int = 0
    malformed_frames: int = 0
    malformed_by_reason: dict[str, int] | None = None
    #: frames the OS dropped before this process read them (a full receive buffer), over
    #: every connection; None when the interface cannot tell (only udp_multicast on Linux can)
    receive_drops: int | None = None


class ReconnectingBus(can.BusABC):
    """A :class:`can.BusABC` that keeps its underlying bus open (see module docstring).

    ``factory`` opens a bus from ``config`` (default :func:`open_bus`); ``clock`` returns
    seconds (monotonic); ``sleep(seconds)`` waits while the link is down (default: an event
    wait that :meth:`shutdown` interrupts). Back-off: the n-th consecutive failed attempt
    waits ``min(backoff_initial * backoff_factor**(n-1), backoff_max)`` [s]; the count resets
    once the link stayed up for ``stable_after`` [s]. ``max_send_failures`` consecutive send
    errors take the link down. Bus-off is seen from ``BusState.ERROR`` (polled every
    ``state_poll_interval`` [s]) and, when ``socketcan_error_frames`` (default: only for the
    socketcan interface, whose error frames carry the error class in the identifier), from
    bus-off error frames; ``reconnect_on_bus_off`` reopens the bus then. ``on_event``
    receives every :class:`LinkEvent` (called from the thread that saw the transition, with
    an internal lock held: keep it short); log warnings are limited to one per
    ``report_interval`` [s]. ``drop_own_echo`` (default: for interfaces that echo, i.e.
    udp_multicast, unless ``receive_own_messages``) removes received copies of frames this bus
    sent (counted in :attr:`own_echoes`). The constructor never raises for an
    unavailable bus: it starts DOWN and retries. After :meth:`shutdown`, ``recv`` raises
    ``can.CanOperationError`` like any closed python-can bus (stop the Notifier first).
    """

    def __init__(
        self,
        config: BusConfig,
        *,
        factory: Callable[[BusConfig], can.BusABC] = open_bus,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], Any] | None = None,
        backoff_initial: float = 0.1,
        backoff_max: float = 5.0,
        backoff_factor: float = 2.0,
        stable_after: float = 10.0,
        max_send_failures: int = 3,
        reconnect_on_bus_off: bool = True,
        socketcan_error_frames: bool | None = None,
        state_poll_interval: float = 1.0,
        report_interval: float = 10.0,
        on_event: Callable[[LinkEvent], None] | None = None,
        logger: logging.Logger | None = None,
        drop_own_echo: bool | None = None,
    ) -> None:
        if not (0 < backoff_initial <= backoff_max and backoff_factor >= 1.0):
            raise BusConfigError("need 0 < backoff_initial <= backoff_max and factor >= 1")
        if max_send_failures < 1:
            raise BusConfigError("max_send_failures must be >= 1")
        # BusABC only stores channel; python-can's Channel type leaves out None (no channel),
        # which can.Bus() itself accepts.
        super().__init__(channel=config.channel, can_filters=None)  # type: ignore[arg-type]
        self.config = config
        self.channel_info = f"reconnecting {config.describe()}"
        self._can_protocol = can.CanProtocol.CAN_FD if config.fd else can.CanProtocol.CAN_20
        self._factory = factory
        self._clock = clock
        self._wake = threading.Event()
        self._sleep = sleep if sleep is not None else self._wake.wait
        self._backoff = (backoff_initial, backoff_max, backoff_factor)
        self._stable_after = stable_after
        self._max_send_failures = max_send_failures
        self._reconnect_on_bus_off = reconnect_on_bus_off
        self._socketcan_errors = (
            config.interface == "socketcan"
            if socketcan_error_frames is None
            else socketcan_error_frames
        )
        self._poll_interval = state_poll_interval
        self._on_event = on_event
        self._log = logger or _LOG
        self._limiter = RateLimiter(report_interval)
        if drop_own_echo is None:
            drop_own_echo = (config.interface in ECHOING_INTERFACES
                             and not config.receive_own_messages)
        self._echo = EchoFilter() if drop_own_echo else None  # bus time: time.time
        self._lock = threading.RLock()
        self._bus: can.BusABC | None = None
        self._readers = ReaderSlot(batch=not self._socketcan_errors)
        self._state = LinkState.CONNECTING
        self._reason = "not yet opened"
        now = clock()
        self._since = now
        self._up_since = now
        self._next_attempt = now
        self._failures = 0  # consecutive failed attempts / drops (back-off exponent)
        self._send_failures_row = 0
        self._next_poll = now
        self.connects = 0
        self.disconnects = 0
        self.failed_attempts = 0
        self.send_failures = 0
        self.bus_off_frames = 0
        #: received datagrams/frames that were no valid CAN frame, dropped (by reason)
        self.malformed: Counter[str] = Counter()
        self._drops_closed: int | None = None  # receive drops of the sockets closed so far
        self._malformed_limiter = RateLimiter(report_interval)
        #: the last 64 transitions
        self.events: deque[LinkEvent] = deque(maxlen=64)
        with self._lock:
            self._connect(now)

    # -- state machine --------------------------------------------------------------------

    def _delay(self) -> float:
        initial, maximum, factor = self._backoff
        return min(initial * factor ** max(self._failures - 1, 0), maximum)

    def _set_state(self, new: LinkState, reason: str, now: float) -> None:
        old = self._state
        self._reason = reason
        if new == old:
            return
        self._state, self._since = new, now
        event = LinkEvent(now, old, new, reason)
        self.events.append(event)
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception:  # a broken callback must not break the bus
                self._log.exception("link event callback failed")
        if new == LinkState.UP:
            self._log.info("CAN %s up", self.config.describe())
        elif new == LinkState.DOWN and self._limiter.allow(now):
            extra = self._limiter.suppressed_at_last_allow
            self._log.warning(
                "CAN %s down: %s (retry in %.2f s%s)",
                self.config.describe(),
                reason,
                self._delay(),
                f", {extra} similar reports suppressed" if extra else "",
            )

    def _connect(self, now: float) -> can.BusABC | None:
        try:
            bus = self._factory(self.config)
        except Exception as err:  # BusUnavailable, BusConfigError, driver errors: retry
            self.failed_attempts += 1
            self._failures += 1
            self._next_attempt = now + self._delay()
            if self._state == LinkState.DOWN and self._limiter.allow(now):
                self._log.warning(
                    "CAN %s still down after %d attempts: %s",
                    self.config.describe(),
                    self._failures,
                    err,
                )
            self._set_state(LinkState.DOWN, f"open failed: {err}", now)
            return None
        self._bus = bus
        self.connects += 1
        self._up_since = now
        self._send_failures_row = 0
        self._next_poll = now + self._poll_interval
        self._set_state(LinkState.UP, "connected", now)
        return bus

    def _fail(self, bus: can.BusABC, reason: str) -> None:
        with self._lock:
            if bus is not self._bus:
                return  # another thread already handled this bus
            self._bus = None
            now = self._clock()
            self.disconnects += 1
            if now - self._up_since >= self._stable_after:
                self._failures = 0
            self._failures += 1
            self._next_attempt = now + self._delay()
            self._set_state(LinkState.DOWN, reason, now)
            self._drops_closed = _add(self._drops_closed, receive_drops(bus))
        try:
            bus.shutdown()
        except Exception as err:  # the adapter may be gone already
            self._log.debug("shutdown of failed bus raised: %s", err)

    def _current(self) -> can.BusABC | None:
        with self._lock:
            if self._bus is not None or self._state == LinkState.CLOSED:
                return self._bus
            now = self._clock()
            if now >= self._next_attempt:
                return self._connect(now)
            return None

    def _poll_state(self, bus: can.BusABC) -> None:
        now = self._clock()
        if now < self._next_poll:
            return
        self._next_poll = now + self._poll_interval
        try:
            state = bus.state
        except Exception:  # not every interface reports a state
            return
        if state == can.BusState.ERROR:
            self._fail(bus, "controller reports bus-off (BusState.ERROR)")

    # -- BusABC interface -----------------------------------------------------------------

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        bus = self._current()
        if bus is None:
            with self._lock:
                if self._state == LinkState.CLOSED:
                    raise can.CanOperationError(f"{self.channel_info} is shut down")
                wait = max(0.0, self._next_attempt - self._clock())
            if timeout is not None:
                wait = min(wait, timeout)
            if wait > 0.0:
                self._sleep(wait)
            return None, False
        try:
            msg = bus.recv(timeout)
            # our own frames looped back: skip them without waiting; when only echoes were
            # queued, recv() goes on waiting for the rest of its timeout
            while msg is not None and self._echo is not None and self._echo.is_echo(msg):
                msg = bus.recv(0.0)
        except Exception as err:  # CanOperationError, OSError, driver errors
            reason = malformed_reason(err)
            if reason is None:
                self._fail(bus, f"receive failed: {type(err).__name__}: {err}")
            else:
                self._count_malformed(reason, err)
            return None, False
        if msg is not None and msg.is_error_frame and self._socketcan_errors:
            bus_off, _ = classify_socketcan_error(msg.arbitration_id, msg.data)
            if bus_off:
                self.bus_off_frames += 1
                if self._reconnect_on_bus_off:
                    self._fail(bus, "bus-off error frame")
        self._poll_state(bus)
        return msg, True  # the underlying bus applied the filters

    def recv_batch(self, timeout: float | None, limit: int = 256) -> list[RawFrame]:
        """Receive what is queued, up to ``limit`` frames, waiting up to ``timeout`` [s].

        :meth:`recv` for many frames at once, as :data:`~clutch_ros.canbus.batch.RawFrame`
        tuples: echoes removed, malformed datagrams counted, failures taking the link down
        alike. On udp_multicast the datagrams are read without a ``can.Message`` each
        (:class:`~clutch_ros.canbus.batch.UdpBatchReader`); other interfaces use :meth:`recv`.
        Raises ``can.CanOperationError`` after :meth:`shutdown`, as :meth:`recv` does.
        """
        try:
            with self._readers.lock:
                return self._recv_batch(timeout, limit)
        finally:
            if self._state == LinkState.CLOSED:  # (after the release: ReaderSlot.close_idle)
                self._readers.close_idle()

    def _recv_batch(self, timeout: float | None, limit: int) -> list[RawFrame]:
        bus = self._current()
        reader = self._readers.reader_for(bus)
        if bus is None or reader is None:
            out, msg = [], self.recv(timeout)
            while msg is not None:
                out.append(message_frame(msg))
                msg = self.recv(0.0) if len(out) < limit else None
            return out
        errors: list[BaseException] = []
        try:
            frames = reader.read(timeout, limit, errors)
        except Exception as err:  # CanOperationError, OSError: as recv()
            self._fail(bus, f"receive failed: {type(err).__name__}: {err}")
            return []
        for bad in errors:
            self._count_malformed(malformed_reason(bad) or "not_a_frame", bad)
        echo = self._echo
        if echo is not None and echo.waiting:  # (only a sent identifier can be an echo)
            ids = echo.pending_ids()
            frames = [f for f in frames if f[1] not in ids or not echo.is_echo_of(
                (f[1], f[2], f[3], f[4], f[5], f[7]), f[0])]
        self._poll_state(bus)
        return frames

    def recv_columns(self, timeout: float | None,
                     limit: int = 256) -> Columns | list[RawFrame]:
        """:meth:`recv_batch` into :class:`~clutch_ros.canbus.intake.Columns`, compiled.

        On udp_multicast (Linux, numba): one ``recvmmsg`` and one compiled parse per call
        (:class:`~clutch_ros.canbus.udp_columns.ColumnReader`), the same frames, echoes,
        counts and failures as :meth:`recv_batch`; elsewhere :meth:`recv_batch`'s list.
        Nothing received: an empty list.
        """
        try:
            with self._readers.lock:
                bus = self._current()
                reader = self._readers.reader_for(bus)
                if bus is None or reader is None:
                    return self._recv_batch(timeout, limit)
                if reader.column_reader is None:
                    reader.column_reader = ColumnReader.for_reader(reader) or False
                if reader.column_reader is False:
                    return self._recv_batch(timeout, limit)
                errors: list[BaseException] = []
                try:
                    cols = reader.column_reader.read(timeout, limit, errors)
                except Exception as err:  # CanOperationError, OSError: as recv()
                    self._fail(bus, f"receive failed: {type(err).__name__}: {err}")
                    return []
                for bad in errors:
                    self._count_malformed(malformed_reason(bad) or "not_a_frame", bad)
                if cols is not None and self._echo is not None and self._echo.waiting:
                    cols = drop_echoes(cols, self._echo)
                self._poll_state(bus)
                return [] if cols is None else cols
        finally:
            if self._state == LinkState.CLOSED:  # (after the release: ReaderSlot.close_idle)
                self._readers.close_idle()

    def _count_malformed(self, reason: str, err: BaseException) -> None:
        with self._lock:
            self.malformed[reason] += 1
            now = self._clock()
            if self._malformed_limiter.allow(now):
                extra = self._malformed_limiter.suppressed_at_last_allow
                self._log.warning(
                    "CAN %s: dropped a malformed frame (%s: %s)%s",
                    self.config.describe(), reason, err.__cause__,
                    f", {extra} more since the last report" if extra else "",
                )

    @property
    def malformed_frames(self) -> int:
        """Number of received datagrams/frames dropped because they were no valid frame."""
        return sum(self.malformed.values())

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` (``timeout`` [s]); raises :class:`BusUnavailable` when it cannot."""
        bus = self._current()
        if bus is None:
            self.send_failures += 1
            raise BusUnavailable(f"CAN {self.config.describe()} is {self._state.value}: "
                                 f"{self._reason}")
        if self._echo is not None:
            self._echo.sent(msg)  # before sending: the echo can arrive before send returns
        try:
            bus.send(msg, timeout)
        except Exception as err:  # CanOperationError, CanTimeoutError, OSError, ...
            if self._echo is not None:
                self._echo.unsent(msg)
            self.send_failures += 1
            with self._lock:
                self._send_failures_row += 1
                row = self._send_failures_row
            if row >= self._max_send_failures:
                self._fail(bus, f"send failed {row} times: {type(err).__name__}: {err}")
            raise BusUnavailable(f"CAN {self.config.describe()}: send failed: {err}") from err
        with self._lock:
            self._send_failures_row = 0

    def try_send(self, msg: can.Message, timeout: float | None = 0.01) -> bool:
        """Send ``msg`` like :meth:`send` but return False instead of raising."""
        try:
            self.send(msg, timeout)
        except BusUnavailable:
            return False
        return True

    @property
    def own_echoes(self) -> int:
        """Number of received echoes of this bus's own frames that were removed."""
        return self._echo.echoes if self._echo is not None else 0

    @property
    def link_state(self) -> LinkState:
        """Current :class:`LinkState`."""
        return self._state

    @property
    def state(self) -> can.BusState:
        """python-can state of the underlying bus; ``BusState.ERROR`` while the link is down."""
        bus = self._bus
        if bus is None:
            return can.BusState.ERROR
        try:
            return bus.state
        except Exception:
            return can.BusState.ACTIVE

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        bus = self._bus
        if bus is None:
            raise BusUnavailable(f"CAN {self.config.describe()} is down")
        bus.state = new_state

    def status(self) -> LinkStatus:
        """Return a :class:`LinkStatus` for diagnostics."""
        with self._lock:
            now = self._clock()
            return LinkStatus(
                state=self._state,
                reason=self._reason,
                since=self._since,
                connects=self.connects,
                disconnects=self.disconnects,
                failed_attempts=self.failed_attempts,
                next_attempt_in=(
                    max(0.0, self._next_attempt - now) if self._state == LinkState.DOWN else 0.0
                ),
                send_failures=self.send_failures,
                bus_off_frames=self.bus_off_frames,
                bus_state=self.state.name,
                suppressed_reports=self._limiter.suppressed,
                own_echoes=self.own_echoes,
                malformed_frames=self.malformed_frames,
                malformed_by_reason=dict(self.malformed),
                receive_drops=self.receive_drops(),
            )

    def receive_drops(self) -> int | None:
        """Frames the OS dropped before they were read, over every connection (None: unknown).

        Only ``udp_multicast`` on Linux can tell (:func:`~clutch_ros.canbus.udp.receive_drops`);
        a SocketCAN controller's own overflows arrive as error frames instead.
        """
        bus = self._bus
        return _add(self._drops_closed, receive_drops(bus) if bus is not None else None)

    def shutdown(self) -> None:
        """Close the link for good (wakes a receiver waiting for the next attempt)."""
        with self._lock:
            bus, self._bus = self._bus, None
            self._set_state(LinkState.CLOSED, "shut down", self._clock())
        self._wake.set()
        self._readers.close_idle()
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as err:
                self._log.debug("shutdown raised: %s", err)
        super().shutdown()
