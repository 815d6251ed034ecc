"""python-can ``udp_multicast`` datagrams parsed into frame columns (compiled: .udp_columns).

Plain Python functions over numpy arrays; :mod:`clutch_ros.canbus.udp_columns` compiles them
with numba. :func:`parse` reads each datagram of a ``recvmmsg(2)`` batch -- its bytes, its
control message (the kernel's ``SO_TIMESTAMPNS`` receive time) -- into the columns of
:class:`clutch_ros.canbus.intake.Columns`, exactly as
:class:`clutch_ros.canbus.batch.UdpBatchReader` reads one with ``msgpack`` and its checks
(``_fast``), and marks every datagram it does not take for that Python path:

* status 0: a frame, written into the columns;
* status 1: anything else -- another msgpack layout than python-can's ``pack_message``
  (a str channel or timestamp, a map16, a negative or too wide integer, a str payload, a
  truncated or over-long datagram), a map whose values fail ``_fast``'s checks, an FD frame
  on a bus opened without FD -- for the Python path, which gives it its frame, its
  ``CanOperationError`` or nothing, as before;
* status 2: the control message is not exactly one ``SO_TIMESTAMPNS`` (the Python path's
  "control message type that was not requested").

msgpack (https://github.com/msgpack/msgpack/blob/master/spec.md): a fixmap of the eleven keys
of ``pack_message`` (any order, each once), fixstr keys, values nil / bool / int / float /
bin, big-endian.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from clutch_ros.model.arraytypes import BoolArray, FloatArray, IntArray

__all__ = ["FIELD_KEYS", "LOOP_FUNCTIONS", "PAYLOAD_STRIDE", "parse"]

#: the keys of python-can's ``pack_message``, in its order (index = field number below)
FIELD_KEYS = ("timestamp", "arbitration_id", "is_extended_id", "is_remote_frame",
              "is_error_frame", "channel", "dlc", "data", "is_fd", "bitrate_switch",
              "error_state_indicator")
(F_TIMESTAMP, F_ID, F_EXT, F_REMOTE, F_ERROR, F_CHANNEL, F_DLC, F_DATA, F_FD, F_BRS,
 F_ESI) = range(11)
#: bytes per frame in the payload column (a CAN FD frame's most)
PAYLOAD_STRIDE = 64
_SOL_SOCKET, _SO_TIMESTAMPNS, _CMSG_LEN = 1, 35, 32  # one cmsghdr (16) + a timespec (16)
_MSG_TRUNC = 0x20
#: the functions compiled (callees first)
LOOP_FUNCTIONS = ("_be", "_le", "_le_signed", "_int", "_skip_scalar", "_key", "parse")


def _be(buf: NDArray[np.uint8], pos: int, width: int) -> int:
    """Unsigned big-endian integer of ``width`` bytes at ``pos`` (at most 7 bytes)."""
    value = 0
    for i in range(width):
        value = (value << 8) | int(buf[pos + i])
    return value


def _int(buf: NDArray[np.uint8], pos: int, end: int) -> tuple[int, int]:
    """``(value, next position)`` of a non-negative msgpack int at ``pos``; next -1: none."""
    if pos >= end:
        return 0, -1
    tag = int(buf[pos])
    if tag <= 0x7F:
        return tag, pos + 1
    width = 0
    if tag == 0xCC or tag == 0xD0:
        width = 1
    elif tag == 0xCD or tag == 0xD1:
        width = 2
    elif tag == 0xCE or tag == 0xD2:
        width = 4
    if width == 0 or pos + 1 + width > end:  # (64-bit and negative ints: the Python path)
        return 0, -1
    value = _be(buf, pos + 1, width)
    if tag >= 0xD0 and value >> (8 * width - 1):  # a negative signed int
        return 0, -1
    return value, pos + 1 + width


def _skip_scalar(buf: NDArray[np.uint8], pos: int, end: int) -> int:
    """Position after a nil, bool, int or float at ``pos`` (-1: another type)."""
    if pos >= end:
        return -1
    tag = int(buf[pos])
    width = -1
    if tag <= 0x7F or tag >= 0xE0 or tag == 0xC0 or tag == 0xC2 or tag == 0xC3:
        width = 0
    elif tag == 0xCC or tag == 0xD0:
        width = 1
    elif tag == 0xCD or tag == 0xD1:
        width = 2
    elif tag == 0xCE or tag == 0xD2 or tag == 0xCA:
        width = 4
    elif tag == 0xCF or tag == 0xD3 or tag == 0xCB:
        width = 8
    if width < 0 or pos + 1 + width > end:
        return -1
    return pos + 1 + width


def _key(buf: NDArray[np.uint8], pos: int, end: int, names: NDArray[np.uint8],
         lengths: IntArray) -> tuple[int, int]:
    """``(field number, next position)`` of a fixstr key at ``pos``; -1: not one of ours."""
    if pos >= end:
        return -1, -1
    tag = int(buf[pos])
    if tag < 0xA0 or tag > 0xBF:
        return -1, -1
    length = tag - 0xA0
    if pos + 1 + length > end:
        return -1, -1
    for k in range(lengths.shape[0]):
        if lengths[k] != length:
            continue
        same = True
        for i in range(length):
            if buf[pos + 1 + i] != names[k, i]:
                same = False
                break
        if same:
            return k, pos + 1 + length
    return -1, -1


def parse(buf: NDArray[np.uint8], stride: int, lens: NDArray[np.uint32],
          flags: NDArray[np.int32], ctrl: NDArray[np.uint8], ctrl_stride: int,
          ctrl_lens: NDArray[np.uint64], n: int, fd_ok: bool, names: NDArray[np.uint8],
          lengths: IntArray, stamp: FloatArray, ident: IntArray, ext: BoolArray,
          remote: BoolArray, error: BoolArray, fd: BoolArray, dlc: IntArray, size: IntArray,
          data: NDArray[np.uint8], status: IntArray) -> tuple[int, int]:
    """Parse datagrams ``0..n-1`` into the columns; ``status`` per datagram (module docstring).

    Datagram ``i``: ``buf[i * stride:][:lens[i]]``, truncated when ``flags[i]`` has
    ``MSG_TRUNC``; its control data ``ctrl[i * ctrl_stride:][:ctrl_lens[i]]``; its payload
    goes to ``data[i * PAYLOAD_STRIDE:]``. ``ctrl_lens`` and ``flags`` are then reset for
    the next ``recvmmsg`` (``ctrl_stride``, 0). Returns the numbers of datagrams with status
    1 and 2.
    """
    value_of = np.zeros(11, np.int64)
    python, bad_control = 0, 0
    for i in range(n):
        truncated = (flags[i] & _MSG_TRUNC) != 0
        control_len = int(ctrl_lens[i])
        flags[i], ctrl_lens[i] = 0, ctrl_stride
        c = i * ctrl_stride
        level = int(ctrl[c + 8]) | int(ctrl[c + 9]) << 8
        kind = int(ctrl[c + 12]) | int(ctrl[c + 13]) << 8
        if (control_len != _CMSG_LEN or _le(ctrl, c, 8) != _CMSG_LEN or level != _SOL_SOCKET
                or _le(ctrl, c + 10, 2) != 0 or kind != _SO_TIMESTAMPNS
                or _le(ctrl, c + 14, 2) != 0):
            status[i] = 2
            bad_control += 1
            continue
        sec, nsec = _le_signed(ctrl, c + 16), _le_signed(ctrl, c + 24)
        stamp[i] = float(sec) + float(nsec) * 1.0e-9
        status[i] = 1
        python += 1
        if truncated:
            continue
        pos, end = i * stride, i * stride + int(lens[i])
        if pos >= end or buf[pos] != 0x8B:  # a fixmap of 11
            continue
        pos += 1
        seen = 0
        value_of[:] = 0
        data_at, data_len = 0, 0
        ok = True
        for _ in range(11):
            k, pos = _key(buf, pos, end, names, lengths)
            if k < 0 or (seen >> k) & 1:
                ok = False
                break
            seen |= 1 << k
            if k == F_TIMESTAMP or k == F_CHANNEL:
                pos = _skip_scalar(buf, pos, end)
            elif k == F_ID or k == F_DLC:
                value_of[k], pos = _int(buf, pos, end)
            elif k == F_DATA:
                tag = int(buf[pos]) if pos < end else 0
                width = 1 if tag == 0xC4 else (2 if tag == 0xC5 else (4 if tag == 0xC6 else 0))
                if width == 0 or pos + 1 + width > end:
                    ok = False
                    break
                data_len = _be(buf, pos + 1, width)
                data_at = pos + 1 + width
                pos = data_at + data_len if data_at + data_len <= end else -1
            else:  # the bools
                tag = int(buf[pos]) if pos < end else 0
                if tag != 0xC2 and tag != 0xC3:
                    ok = False
                    break
                value_of[k], pos = tag - 0xC2, pos + 1
            if pos < 0:
                ok = False
                break
        if not ok or pos != end:
            continue
        # the checks of batch._fast (else the Python path: its error, or its frame)
        ident_i, dlc_i = value_of[F_ID], value_of[F_DLC]
        is_ext, is_remote, is_error, is_fd = (value_of[F_EXT] == 1, value_of[F_REMOTE] == 1,
                                              value_of[F_ERROR] == 1, value_of[F_FD] == 1)
        if ident_i >= (0x20000000 if is_ext else 0x800) or dlc_i > (64 if is_fd else 8):
            continue
        if is_remote:
            if is_error or is_fd:
                continue
            data_len = 0
        elif dlc_i != data_len:
            continue
        if not is_fd and (value_of[F_BRS] == 1 or value_of[F_ESI] == 1):
            continue
        if is_fd and not fd_ok:  # ignored, as python-can does: the Python path skips it
            continue
        ident[i], ext[i], remote[i], error[i], fd[i] = ident_i, is_ext, is_remote, is_error, is_fd
        dlc[i], size[i] = dlc_i, data_len
        base = i * PAYLOAD_STRIDE
        for b in range(data_len):
            data[base + b] = buf[data_at + b]
        status[i] = 0
        python -= 1
    return python, bad_control


def _le(buf: NDArray[np.uint8], pos: int, width: int) -> int:
    """Unsigned little-endian integer of ``width`` bytes at ``pos`` (8: wraps above 2**63)."""
    value = 0
    for i in range(width - 1, -1, -1):
        value = (value << 8) | int(buf[pos + i])
    return value


def _le_signed(buf: NDArray[np.uint8], pos: int) -> int:
    """Signed little-endian 64-bit integer at ``pos`` (a timespec field)."""
    value = np.uint64(0)
    for i in range(7, -1, -1):
        value = (value << np.uint64(8)) | np.uint64(buf[pos + i])
    return int(np.int64(value))
