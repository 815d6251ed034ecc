"""Frames as plain tuples, read in batches: a full bus without an object per frame.

python-can hands every frame over as a :class:`can.Message` (on ``udp_multicast``: a select,
a recvmsg, a msgpack dict and a checked ``Message`` per frame, behind two ``BusABC.recv``
layers). At 8,000 frames/s that cost more CPU than the decoding. This module reads
``udp_multicast`` datagrams straight from the socket (one ``recvmsg`` system call each, on a
duplicate of its descriptor: :class:`UdpBatchReader`), as many as are queued per wake-up, into
:data:`RawFrame` tuples; :meth:`clutch_ros.canbus.bus.ReconnectingBus.recv_batch` uses it
(other interfaces go through python-can's ``recv`` and :func:`message_frame`).

Exactness: a datagram whose msgpack map is exactly what python-can's ``pack_message`` writes
(its eleven keys, ``bool`` flags, ``int`` identifier and DLC, ``bytes`` payload) and passes
the checks of ``can.Message(check=True)`` becomes a tuple directly; any other datagram goes
through python-can's own ``unpack_message(..., check=True)``, so a malformed one fails with
the same exception (and the same :func:`~clutch_ros.canbus.udp.malformed_reason`) as on
python-can's path. The receive time is the kernel's ``SO_TIMESTAMPNS``, as python-can's. FD
frames are ignored on a bus opened without FD, as python-can does.
"""

from __future__ import annotations

import os
import select
import socket
import struct
import threading
from typing import Any

import can
from can.interfaces.udp_multicast.utils import msgpack, unpack_message  # (None: not installed)

from clutch_ros.canbus.errors import PayloadTooLongError

__all__ = ["RawFrame", "ReaderSlot", "UdpBatchReader", "frame_message", "message_frame"]

#: A frame: (bus time [s], identifier, is_extended, is_remote, is_error, is_fd, dlc, payload);
#: the argument order of :meth:`clutch_ros.canbus.assembler.RigStateAssembler.feed_frame`.
RawFrame = tuple[float, int, bool, bool, bool, bool, int, bytes]

_KEYS = frozenset({"timestamp", "arbitration_id", "is_extended_id", "is_remote_frame",
                   "is_error_frame", "channel", "dlc", "data", "is_fd", "bitrate_switch",
                   "error_state_indicator"})
_SO_TIMESTAMPNS = 35  # linux/asm-generic/socket.h (python-can's constant)
_TIMESPEC = struct.Struct("@ll")


def message_frame(msg: can.Message) -> RawFrame:
    """Return the :data:`RawFrame` of a python-can message."""
    return (float(msg.timestamp), msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame,
            msg.is_error_frame, msg.is_fd, msg.dlc, bytes(msg.data))


def frame_message(frame: RawFrame) -> can.Message:
    """Return a :class:`can.Message` of a :data:`RawFrame` (for the optional raw topic)."""
    stamp, ident, ext, remote, error, fd, dlc, data = frame
    return can.Message(timestamp=stamp, arbitration_id=ident, is_extended_id=ext,
                       is_remote_frame=remote, is_error_frame=error, is_fd=fd, dlc=dlc,
                       data=data)


class UdpBatchReader:
    """Read the queued datagrams of a python-can ``udp_multicast`` bus as :data:`RawFrame`.

    Use :meth:`for_bus`: None when the bus is no udp_multicast bus this can read exactly
    (no kernel timestamps, software CAN filters set, other python-can internals).
    """

    def __init__(self, sock: socket.socket, fd: bool, max_buffer: int = 4096) -> None:
        self.sock, self.fd, self.max_buffer = sock, fd, max_buffer
        self._ancillary = socket.CMSG_SPACE(_TIMESPEC.size)
        # python-can gives its socket a send timeout, and CPython then polls before every
        # recvmsg on it (MSG_DONTWAIT or not), after a poll(0) of ours for an empty queue:
        # three system calls per datagram. A duplicate of the descriptor in a socket object
        # without a timeout reads a datagram in one: recvmsg(MSG_DONTWAIT) raises
        # BlockingIOError when the queue is empty, whatever the shared descriptor's blocking
        # flag (python-can's send may switch it), and the duplicate never changes that flag.
        # It is this reader's own descriptor: :meth:`close` closes it.
        self._own: socket.socket | None = None
        try:
            self._own = socket.socket(fileno=os.dup(sock.fileno()))
        except OSError:  # (no descriptor left: the three-call path below)
            pass
        if self._own is not None and self._own.gettimeout() is not None:  # a default
            self._own.close()  # timeout set: the one-call path is not available
            self._own = None
        self._poll = select.poll()
        self._poll.register(sock, select.POLLIN)
        #: its compiled twin (:class:`clutch_ros.canbus.udp_columns.ColumnReader`), made by
        #: the bus at the first :meth:`~clutch_ros.canbus.bus.ReconnectingBus.recv_columns`
        #: (False: not available here)
        self.column_reader: Any = None

    def close(self) -> None:
        """Close this reader's duplicate of the socket (the bus's own stays as it is)."""
        if self._own is not None:
            self._own.close()

    @classmethod
    def for_bus(cls, bus: can.BusABC) -> UdpBatchReader | None:
        """Return a reader of ``bus``'s socket, or None (see the class docstring)."""
        multicast = getattr(bus, "_multicast", None)
        sock = getattr(multicast, "_socket", None)
        if (sock is None or msgpack is None
                or not getattr(multicast, "timestamp_nanosecond", False)
                or getattr(bus, "_filters", None) or not hasattr(socket, "CMSG_SPACE")):
            return None
        return cls(sock, bus.protocol is can.CanProtocol.CAN_FD,
                   getattr(multicast, "max_buffer", 4096))

    def read(self, timeout: float | None, limit: int,
             errors: list[BaseException]) -> list[RawFrame]:
        """Wait up to ``timeout`` [s] for a datagram, then read up to ``limit`` queued ones.

        Datagrams that are no valid frame append their ``can.CanOperationError`` (caused as
        on python-can's path) to ``errors`` and are skipped. Raises ``can.CanOperationError``
        when the socket fails before any frame was read (after: the frames read are returned,
        and the next call meets the failure).
        """
        sock, own, out = self.sock, self._own, list[RawFrame]()
        try:  # (on this reader's own descriptor when it has one: valid while it reads)
            ready, _, _ = select.select([own or sock], [], [], timeout)
        except OSError as exc:
            raise can.CanOperationError(f"Failed to wait for IP/UDP socket: {exc}") from exc
        if not ready:
            return out
        recvmsg, size, anc, dontwait = ((own or sock).recvmsg, self.max_buffer,
                                        self._ancillary, socket.MSG_DONTWAIT)
        frame_of, poll, more = self.frame_of, self._poll.poll, False
        while len(out) < limit:
            if more and own is None and not poll(0):
                break
            more = True
            try:
                raw, ancillary, _, _ = recvmsg(size, anc, dontwait)
            except BlockingIOError:
                break
            except OSError as exc:
                if out:
                    break
                raise can.CanOperationError("failed to receive via socket") from exc
            if len(ancillary) != 1 or ancillary[0][0] != socket.SOL_SOCKET \
                    or ancillary[0][1] != _SO_TIMESTAMPNS:
                raise can.CanOperationError("received control message type that was not "
                                            "requested")
            sec, nsec = _TIMESPEC.unpack(ancillary[0][2])
            frame = frame_of(raw, sec + nsec * 1.0e-9, errors)
            if frame is not None:
                out.append(frame)
        return out

    def frame_of(self, raw: bytes, stamp: float,
                 errors: list[BaseException]) -> RawFrame | None:
        """Return the frame of one datagram received at ``stamp`` [s], as :meth:`read` does.

        None when it is no valid frame (its ``can.CanOperationError`` appended to ``errors``)
        or an FD frame on a bus opened without FD (ignored).
        """
        assert msgpack is not None  # for_bus made no reader without it
        frame, d = None, None
        try:
            d = msgpack.unpackb(raw, raw=False)
            if type(d) is dict and d.keys() == _KEYS:
                frame = _fast(stamp, d)
        except Exception:  # noqa: BLE001 - python-can's own unpacking below says why
            frame = None
        if frame is None:
            try:
                frame = _slow(raw, stamp, d)
            except can.CanOperationError as err:
                errors.append(err)
                return None
        return None if frame[5] and not self.fd else frame

    def own_socket(self) -> socket.socket:
        """Return the socket this reader reads: its duplicate, else the bus's."""
        return self._own or self.sock


class ReaderSlot:
    """The :class:`UdpBatchReader` of a bus's current connection, closed when it changes.

    One thread reads (``ReconnectingBus.recv_batch``, the can_bridge's receive thread),
    holding :attr:`lock` while it does, so a reader's descriptor is never closed under a read.
    ``batch``: False where every interface must take python-can's ``recv`` (no reader).
    """

    def __init__(self, batch: bool = True) -> None:
        self.batch = batch
        self.lock = threading.Lock()  # held by the reading thread while it reads
        self.bus: can.BusABC | None = None
        self.reader: UdpBatchReader | None = None

    def reader_for(self, bus: can.BusABC | None) -> UdpBatchReader | None:
        """Return the reader of ``bus`` (None: none can read it), made when the bus is new.

        The previous bus's reader is closed first. Call with :attr:`lock` held.
        """
        if bus is not self.bus:
            self._close()
            if bus is not None and self.batch:
                self.bus, self.reader = bus, UdpBatchReader.for_bus(bus)
            else:
                self.bus = bus
        return self.reader if bus is not None else None

    def close_idle(self) -> None:
        """After the bus closed for good: close the reader now, or leave it to the reader.

        The link is closed before either side calls this; the reading thread calls it after
        releasing :attr:`lock`, so one of the two takes the lock after the close, and the
        reader's socket closes.
        """
        if self.lock.acquire(blocking=False):
            try:
                self._close()
            finally:
                self.lock.release()

    def _close(self) -> None:
        reader, self.bus, self.reader = self.reader, None, None
        if reader is not None:
            reader.close()


def _fast(stamp: float, d: dict[str, Any]) -> RawFrame | None:
    """Return the frame of a msgpack map as python-can writes it, None if anything differs."""
    ident, ext, remote, error = (d["arbitration_id"], d["is_extended_id"],
                                 d["is_remote_frame"], d["is_error_frame"])
    fd, dlc, data = d["is_fd"], d["dlc"], d["data"]
    if not (type(ident) is int and type(dlc) is int and type(data) is bytes
            and type(ext) is bool and type(remote) is bool and type(error) is bool
            and type(fd) is bool and type(d["bitrate_switch"]) is bool
            and type(d["error_state_indicator"]) is bool):
        return None
    if not 0 <= ident < (0x20000000 if ext else 0x800) or not 0 <= dlc <= (64 if fd else 8):
        return None
    if remote:
        if error or fd:
            return None
        data = b""  # can.Message drops a remote frame's payload
    elif dlc != len(data):
        return None
    if not fd and (d["bitrate_switch"] or d["error_state_indicator"]):
        return None
    return (stamp, ident, ext, remote, error, fd, dlc, data)


def _slow(raw: bytes, stamp: float, unpacked: Any = None) -> RawFrame:
    """python-can's own unpacking (``check=True``), raising as its udp_multicast bus does.

    ``unpacked``: the datagram's msgpack value when it was read. A map whose ``data`` is a
    count above 64 is refused before python-can makes that many bytes
    (:class:`~clutch_ros.canbus.errors.PayloadTooLongError`).
    """
    size = unpacked.get("data") if type(unpacked) is dict else None
    if type(size) is int and size > 64:
        raise can.CanOperationError("could not unpack received message") from \
            PayloadTooLongError(f"data of {size} bytes (a frame has at most 64)")
    try:
        msg = unpack_message(raw, replace={"timestamp": stamp}, check=True)
    except Exception as exception:
        raise can.CanOperationError("could not unpack received message") from exception
    return message_frame(msg)
