"""python-can ``udp_multicast`` specifics: the echo of our own frames and socket tuning.

python-can's ``udp_multicast`` interface (the bus between processes on one machine) differs
from a CAN adapter in two ways that matter to a node:

* it loops every frame a bus sends back to that bus (the socket joins the group it sends
  to), although it rejects ``receive_own_messages``: :class:`EchoFilter` recognises those
  echoes, and :class:`~clutch_ros.canbus.bus.ReconnectingBus` removes them;
* on Linux a socket bound to the port hears every group joined on that port, and its default
  receive buffer holds only ~20 ms of traffic at 10,000 frames/s: :func:`tune_udp_multicast`
  (applied by :func:`~clutch_ros.canbus.bus.open_bus`) fixes both; what a full buffer still
  drops, the kernel counts, and :func:`receive_drops` reads.

A datagram that is no CAN frame (not msgpack, an 11-bit identifier above 0x7FF, a DLC that
differs from the data length, ...) makes python-can's ``recv`` raise ``CanOperationError``
although the socket is fine and the datagram is already consumed. :func:`malformed_reason`
tells such a per-datagram error from a transport failure, so the bus counts and drops it
instead of taking the link down.
"""

from __future__ import annotations

import math
import os
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable

import can

from clutch_ros.canbus.errors import PayloadTooLongError

__all__ = [
    "ECHOING_INTERFACES",
    "MALFORMED_REASONS",
    "UDP_RECEIVE_BUFFER",
    "EchoFilter",
    "malformed_reason",
    "receive_drops",
    "tune_udp_multicast",
]

#: Receive buffer [bytes] requested for udp_multicast sockets (capped by net.core.rmem_max).
UDP_RECEIVE_BUFFER = 4 * 1024 * 1024
_IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)  # linux/in.h
_IPV6_MULTICAST_ALL = getattr(socket, "IPV6_MULTICAST_ALL", 29)  # linux/in6.h
#: Interfaces that deliver a node's own frames back to it even without receive_own_messages.
ECHOING_INTERFACES = frozenset({"udp_multicast"})


def tune_udp_multicast(bus: can.BusABC, receive_buffer: int = UDP_RECEIVE_BUFFER) -> bool:
    """Tune a python-can ``udp_multicast`` bus's socket (Linux); True when fully done.

    * Group isolation: Linux delivers every multicast datagram for a port to every socket
      bound to that port whose host joined the group (``IP_MULTICAST_ALL`` defaults to 1), so
      two buses on different groups but the same port hear each other. Clearing the option
      restores the isolation the group is meant to give.
    * Receive buffer: the default (``net.core.rmem_default``, ~208 KiB) holds only a few
      hundred frames, ~20 ms at 10,000 frames/s, so a short stall of the receiving process
      loses frames. ``receive_buffer`` [bytes] is requested (the kernel caps it at
      ``net.core.rmem_max``).

    Best effort: False on other systems or when the python-can internals differ.
    """
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if sock is None or not sys.platform.startswith("linux"):
        return False
    if sock.family == socket.AF_INET6:
        level, option = socket.IPPROTO_IPV6, _IPV6_MULTICAST_ALL
    else:
        level, option = socket.IPPROTO_IP, _IP_MULTICAST_ALL
    try:
        sock.setsockopt(level, option, 0)
        if receive_buffer:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    except OSError:
        return False
    return True

def receive_drops(bus: can.BusABC) -> int | None:
    """Datagrams the kernel dropped at a ``udp_multicast`` bus's socket, or None if unknown.

    A process that falls behind (a busy machine, a burst of 10,000 frames/s) lets the
    socket's receive buffer fill; the kernel then drops datagrams, counted per socket in the
    last column (``drops``) of ``/proc/net/udp`` and ``/proc/net/udp6``, found by the
    socket's inode. Linux only; None for other interfaces and systems.
    """
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if sock is None or not sys.platform.startswith("linux"):
        return None
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
    except (OSError, ValueError):  # closed meanwhile
        return None
    table = "/proc/self/net/udp6" if sock.family == socket.AF_INET6 else "/proc/self/net/udp"
    try:
        with open(table) as rows:
            next(rows, None)  # the header
            for row in rows:
                cols = row.split()
                if len(cols) >= 13 and cols[9] == inode:
                    return int(cols[-1])
    except (OSError, ValueError):
        return None
    return None


#: The reasons :func:`malformed_reason` returns (a fixed set: bounded diagnostics).
MALFORMED_REASONS = ("not_msgpack", "invalid_frame", "not_a_frame")


def malformed_reason(err: BaseException) -> str | None:
    """Return why a received datagram was no valid frame, or None for a transport failure.

    python-can wraps both kinds in ``can.CanOperationError``; the cause tells them apart. A
    socket or driver failure is caused by an ``OSError`` or a python-can error (or has no
    cause); a bad datagram is caused by the unpacking (``"not_msgpack"``: msgpack could not
    parse it), by :class:`can.Message`'s check (``"invalid_frame"``: ``ValueError``, e.g.
    an 11-bit identifier above 0x7FF or a DLC that differs from the data length) or by
    fields that do not make a frame (``"not_a_frame"``: msgpack held something else).
    """
    if not isinstance(err, can.CanOperationError):
        return None
    cause = err.__cause__
    if cause is None or isinstance(cause, (OSError, can.CanError)):
        return None
    if isinstance(cause, PayloadTooLongError):
        return "invalid_frame"
    if _raised_in_can_message(cause):  # can.Message(check=True) rejected the fields
        return "invalid_frame" if isinstance(cause, ValueError) else "not_a_frame"
    if isinstance(cause, ValueError) or type(cause).__module__.split(".")[0] == "msgpack":
        return "not_msgpack"  # msgpack's C unpacker raises ValueError subclasses
    return "not_a_frame"


def _raised_in_can_message(exc: BaseException) -> bool:
    """Return True when ``exc`` was raised inside ``can/message.py`` (its innermost frame)."""
    tb = exc.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    return tb.tb_frame.f_code.co_filename == _MESSAGE_FILE


_MESSAGE_FILE = can.message.__file__

#: what identifies an echoed frame: identifier, flags and payload
_Signature = tuple[int, bool, bool, bool, bool, bytes]


def _signature(msg: can.Message) -> _Signature:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_error_frame,
            msg.is_fd, bytes(msg.data))


class EchoFilter:
    """Recognise the echoes of frames this node sent (thread-safe).

    :meth:`sent` records a frame before it is sent (:meth:`unsent` takes it back when the
    send fails); :meth:`is_echo` returns True -- once per recorded copy -- for a received
    frame equal to one sent at most ``window`` [s] before the frame's receive timestamp
    (identifier, flags and payload). At most ``capacity`` frames are remembered, so an
    interface that stops echoing costs bounded memory. ``clock`` returns the current time
    [s] in the time base of the received frames' timestamps (udp_multicast: the kernel
    receive time, ``time.time``); a frame without a timestamp is taken as received now.

    Records expire in *stream* time, by the timestamps of the frames received, never by the
    clock alone: a reader that falls behind (10,000 frames/s of fuzz queued for over a second
    in the socket) still meets its echoes, which arrive in order after the frames sent
    before them; expiring them by the clock had counted 16 own PumpRequests as another
    node's in such a burst.
    """

    def __init__(self, clock: Callable[[], float] = time.time, window: float = 1.0,
                 capacity: int = 4096) -> None:
        self._clock = clock
        self._window = window
        self._capacity = capacity
        self._lock = threading.Lock()
        self._order: deque[tuple[float, _Signature]] = deque()
        self._pending: dict[_Signature, int] = {}
        #: echoes recognised and removed
        self.echoes = 0

    @property
    def waiting(self) -> bool:
        """True while a sent frame's echo is expected (else no frame can be an echo)."""
        return bool(self._pending)

    def pending_ids(self) -> frozenset[int]:
        """Return the identifiers of frames whose echo is expected (no other can be an echo)."""
        with self._lock:
            return frozenset(sig[0] for sig in self._pending)

    def _expire(self, stream_time: float | None) -> None:
        """Forget records sent over ``window`` before ``stream_time`` [s] and above capacity.

        ``stream_time`` None: the capacity only.
        """
        order, pending = self._order, self._pending
        horizon = -math.inf if stream_time is None else stream_time - self._window
        while order and (order[0][0] < horizon or len(order) > self._capacity):
            _, sig = order.popleft()
            left = pending.get(sig, 0) - 1
            if left > 0:
                pending[sig] = left
            else:
                pending.pop(sig, None)

    def sent(self, msg: can.Message) -> None:
        """Record ``msg`` as about to be sent."""
        sig = _signature(msg)
        with self._lock:
            self._order.append((self._clock(), sig))
            self._pending[sig] = self._pending.get(sig, 0) + 1
            self._expire(None)

    def unsent(self, msg: can.Message) -> None:
        """Forget the most recent record of ``msg`` (its send failed)."""
        sig = _signature(msg)
        with self._lock:
            for i in range(len(self._order) - 1, -1, -1):
                if self._order[i][1] == sig:
                    del self._order[i]
                    left = self._pending.get(sig, 0) - 1
                    if left > 0:
                        self._pending[sig] = left
                    else:
                        self._pending.pop(sig, None)
                    return

    def is_echo(self, msg: can.Message) -> bool:
        """Return True (and forget one record) when ``msg`` is the echo of a sent frame."""
        if not self._pending:
            return False
        return self.is_echo_of(_signature(msg), float(msg.timestamp))

    def is_echo_of(self, sig: _Signature, stamp: float) -> bool:
        """:meth:`is_echo` for a frame's signature received at bus time ``stamp`` [s].

        The signature: (identifier, is_extended, is_remote, is_error, is_fd, payload bytes).
        """
        if not self._pending:
            return False
        with self._lock:
            self._expire(stamp if math.isfinite(stamp) and stamp > 0.0 else self._clock())
            count = self._pending.get(sig, 0)
            if count == 0:
                return False
            for i, (_, recorded) in enumerate(self._order):
                if recorded == sig:
                    del self._order[i]
                    break
            if count > 1:
                self._pending[sig] = count - 1
            else:
                del self._pending[sig]
            self.echoes += 1
            return True

