"""A udp_multicast bus's queued datagrams read in one system call into frame columns.

:class:`ColumnReader` is the compiled twin of
:meth:`clutch_ros.canbus.batch.UdpBatchReader.read` for the can_bridge's compiled intake
(``bridge.compiled``): one ``recvmmsg(2)`` (libc, through ctypes) takes every queued datagram
into preallocated buffers, and :func:`clutch_ros.canbus.udp_kernel.parse` (numba) reads
python-can's msgpack layout and the kernel's receive time into
:class:`~clutch_ros.canbus.intake.Columns` -- no Python object per frame. A datagram the
kernel does not take (another layout, a malformed one, an FD frame on a bus opened without
FD) goes through :meth:`UdpBatchReader.frame_of`, the Python path's own code, so the frames,
the errors and what is ignored are the same (``tests/canbus/test_udp_columns.py`` checks the
two readers on the same datagrams).

Linux with a 64-bit ``struct mmsghdr`` (x86_64, aarch64) only: :meth:`ColumnReader.for_reader`
returns None elsewhere, and the caller reads with :meth:`UdpBatchReader.read`.
"""

from __future__ import annotations

import ctypes
import errno
import os
import select
import socket
import sys
import threading
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from clutch_ros.canbus import udp_kernel as kern
from clutch_ros.canbus.batch import UdpBatchReader
from clutch_ros.canbus.intake import (
    Columns,
    compiled_functions,
    compress,
    frame_at,
    take,
    unavailable_reason,
)
from clutch_ros.canbus.intake import warm_up as intake_warm_up
from clutch_ros.canbus.udp import EchoFilter

__all__ = ["ColumnReader", "available", "drop_echoes", "warm_up"]

#: struct mmsghdr on LP64 Linux: struct msghdr (56 bytes) and msg_len
_MMSGHDR = np.dtype({"names": ["name", "namelen", "iov", "iovlen", "control", "controllen",
                               "flags", "msg_len"],
                     "formats": ["<u8", "<u4", "<u8", "<u8", "<u8", "<u8", "<i4", "<u4"],
                     "offsets": [0, 8, 16, 24, 32, 40, 48, 56], "itemsize": 64})
_IOVEC = np.dtype({"names": ["base", "len"], "formats": ["<u8", "<u8"], "itemsize": 16})
_CONTROL = 32  # CMSG_SPACE(sizeof(struct timespec)): what UdpBatchReader asks for too
_LOCK = threading.Lock()
_state: dict[str, Any] = {"parse": None, "recvmmsg": None, "tried": False}


def _set_up() -> tuple[Callable[..., tuple[int, int]], Any] | None:
    """Return ``(compiled parse, libc recvmmsg)``, None where they are not available."""
    with _LOCK:
        if not _state["tried"]:
            _state["tried"] = True
            if sys.platform.startswith("linux") and ctypes.sizeof(ctypes.c_void_p) == 8:
                try:
                    libc = ctypes.CDLL(None, use_errno=True)
                    call = libc.recvmmsg
                    call.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_uint,
                                     ctypes.c_int, ctypes.c_void_p]
                    call.restype = ctypes.c_int
                except (OSError, AttributeError):
                    call = None
                parse = compiled_functions(kern, kern.LOOP_FUNCTIONS, _warm_up)
                if call is not None and parse is not None:
                    _state["parse"], _state["recvmmsg"] = parse, call
        if _state["parse"] is None:
            return None
        return _state["parse"], _state["recvmmsg"]


class ColumnReader:
    """Read ``reader``'s socket a batch at a time into columns (module docstring).

    Use :meth:`for_reader`. ``capacity``: the most datagrams one call takes.
    """

    def __init__(self, reader: UdpBatchReader, parse: Callable[..., tuple[int, int]],
                 recvmmsg: Any,
                 capacity: int = 256) -> None:
        self.reader, self._parse, self._recvmmsg = reader, parse, recvmmsg
        self.capacity, self._stride = capacity, reader.max_buffer
        self._buf = np.zeros(capacity * self._stride, np.uint8)
        self._ctrl = np.zeros(capacity * _CONTROL, np.uint8)
        self._iov = np.zeros(capacity, _IOVEC)
        self._iov["base"] = self._buf.ctypes.data + self._stride * np.arange(capacity)
        self._iov["len"] = self._stride
        self._hdr = np.zeros(capacity, _MMSGHDR)
        self._hdr["iov"] = self._iov.ctypes.data + _IOVEC.itemsize * np.arange(capacity)
        self._hdr["iovlen"] = 1
        self._hdr_address = self._hdr.ctypes.data
        self._hdr["control"] = self._ctrl.ctypes.data + _CONTROL * np.arange(capacity)
        self._hdr["controllen"] = _CONTROL
        # views of the fields the kernel writes (msg_len, controllen, flags) and parse reads
        # and resets (controllen, flags) for the next call
        self._lens, self._ctrl_lens, self._flags = (self._hdr["msg_len"],
                                                    self._hdr["controllen"], self._hdr["flags"])
        n = capacity
        self._cols = Columns(np.zeros(n), np.zeros(n, np.int64), np.zeros(n, np.bool_),
                             np.zeros(n, np.bool_), np.zeros(n, np.bool_), np.zeros(n, np.bool_),
                             np.zeros(n, np.int64), np.zeros(n, np.int64),
                             np.zeros(n * kern.PAYLOAD_STRIDE, np.uint8),
                             kern.PAYLOAD_STRIDE * np.arange(n, dtype=np.int64))
        self._status = np.zeros(n, np.int64)
        names = [k.encode() for k in kern.FIELD_KEYS]
        self._names = np.zeros((len(names), max(map(len, names))), np.uint8)
        for i, name in enumerate(names):
            self._names[i, :len(name)] = np.frombuffer(name, np.uint8)
        self._lengths = np.array([len(k) for k in names], np.int64)

    @classmethod
    def for_reader(cls, reader: UdpBatchReader) -> ColumnReader | None:
        """Return a column reader of ``reader``'s socket (None: not available here)."""
        parts = _set_up()
        return None if parts is None else cls(reader, *parts)

    def read(self, timeout: float | None, limit: int,
             errors: list[BaseException]) -> Columns | None:
        """Wait up to ``timeout`` [s] for a datagram, then read up to ``limit`` queued ones.

        Returns their frames as columns (None: none), in the order received. As
        :meth:`UdpBatchReader.read`: datagrams that are no valid frame append their
        ``can.CanOperationError`` to ``errors`` and are left out; raises
        ``can.CanOperationError`` when the socket fails or a control message is not the
        receive time. The columns are this reader's buffers: valid until the next call.
        """
        sock = self.reader.own_socket()
        try:
            ready, _, _ = select.select([sock], [], [], timeout)
        except OSError as exc:
            raise can.CanOperationError(f"Failed to wait for IP/UDP socket: {exc}") from exc
        if not ready:
            return None
        n = self._recvmmsg(sock.fileno(), self._hdr_address, min(limit, self.capacity),
                           socket.MSG_DONTWAIT, None)
        if n < 0:
            code = ctypes.get_errno()
            if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                return None
            raise can.CanOperationError("failed to receive via socket") from OSError(
                code, os.strerror(code))
        if n == 0:
            return None
        cols, status = self._cols, self._status
        python, bad_control = self._parse(
            self._buf, self._stride, self._lens, self._flags, self._ctrl, _CONTROL,
            self._ctrl_lens, n, self.reader.fd, self._names, self._lengths, *cols[:9], status)
        if bad_control:
            raise can.CanOperationError("received control message type that was not requested")
        if not python:
            return take(cols, slice(0, n))
        keep = None
        for i in np.flatnonzero(status[:n] == 1).tolist():
            start = i * self._stride
            frame = self.reader.frame_of(self._buf[start:start + int(self._lens[i])].tobytes(),
                                         float(cols.stamp[i]), errors)
            if frame is None:
                keep = np.ones(n, np.bool_) if keep is None else keep
                keep[i] = False
                continue
            _, ident, ext, remote, error, fd, dlc, data = frame
            cols.ident[i], cols.ext[i], cols.remote[i], cols.error[i] = ident, ext, remote, error
            cols.fd[i], cols.dlc[i], cols.size[i] = fd, dlc, len(data)
            base = i * kern.PAYLOAD_STRIDE
            cols.data[base:base + len(data)] = np.frombuffer(data, np.uint8)
        view = take(cols, slice(0, n))
        return view if keep is None else compress(view, keep)


def warm_up() -> str | None:
    """Compile the can_bridge's kernels (intake, parser) into numba's cache now.

    Returns why they cannot be used, else None. ``tools/bootstrap.sh`` calls it after an
    install, so a bridge's first configure loads them instead of compiling for seconds.
    """
    reason = intake_warm_up()
    available()
    return reason or unavailable_reason()


def available() -> bool:
    """Return True when :class:`ColumnReader` can read here (compiling its parser once)."""
    return _set_up() is not None


def drop_echoes(cols: Columns, echo: EchoFilter) -> Columns | None:
    """Return ``cols`` without the echoes of frames this node sent (None: nothing left)."""
    found: list[int] = []
    for ident in echo.pending_ids():  # (one or two: the identifiers this node sends)
        found += np.flatnonzero(cols.ident == ident).tolist()
    if not found:
        return cols
    keep = np.ones(cols.stamp.size, np.bool_)
    for i in found:
        f = frame_at(cols, i)
        keep[i] = not echo.is_echo_of((f[1], f[2], f[3], f[4], f[5], f[7]), f[0])
    return compress(cols, keep)


def _warm_up(parse: Callable[..., tuple[int, int]]) -> None:
    """Call ``parse`` once with arguments of the types :meth:`ColumnReader.read` passes."""
    i8, u8, b1 = np.int64, np.uint8, np.bool_
    one, hdr = np.zeros(1, i8), np.zeros(1, _MMSGHDR)
    parse(np.zeros(64, u8), 64, hdr["msg_len"], hdr["flags"], np.zeros(_CONTROL, u8), _CONTROL,
          hdr["controllen"], 0, False, np.zeros((1, 1), u8), one, np.zeros(1), one,
          np.zeros(1, b1), np.zeros(1, b1), np.zeros(1, b1), np.zeros(1, b1), one, one,
          np.zeros(64, u8), one)
