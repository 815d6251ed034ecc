"""Exceptions of the CAN layer (:mod:`clutch_ros.canbus`).

All derive from :class:`CanError`, itself a :class:`clutch_ros.errors.ClutchError`, so the CLI
and the nodes can catch one base class. Foreign errors (python-can, cantools, OS) are wrapped
with ``raise ... from err`` so the original traceback stays available.

Hierarchy::

    ClutchError
     +-- CanError
          +-- DbcError            (also ConfigError)  DBC file missing or invalid
          +-- EncodeError                             a value cannot be put into a frame
          +-- FrameDecodeError    (also DataError)    a known frame cannot be decoded
          +-- BusConfigError      (also ConfigError)  invalid bus configuration
          +-- BusUnavailable                          bus cannot be opened / link is down
          +-- LogFileError        (also DataError)    CAN log file unreadable or corrupt
          +-- PayloadTooLongError (also DataError, ValueError) a datagram's payload count > 64
"""

from clutch_ros.errors import ClutchError, ConfigError, DataError

__all__ = [
    "BusConfigError",
    "BusUnavailable",
    "CanError",
    "DbcError",
    "EncodeError",
    "FrameDecodeError",
    "LogFileError",
    "PayloadTooLongError",
]


class CanError(ClutchError):
    """Base class of every error raised by :mod:`clutch_ros.canbus`."""


class DbcError(CanError, ConfigError):
    """The CAN database (DBC) cannot be loaded or lacks what the rig needs."""


class EncodeError(CanError):
    """A value cannot be encoded into a frame (NaN, out of range, unknown signal)."""


class FrameDecodeError(CanError, DataError):
    """A frame with a known identifier cannot be decoded.

    ``reason`` is one of ``"dlc"`` (wrong data length), ``"checksum"`` (E2E checksum wrong),
    ``"payload"`` (cantools could not decode the payload), ``"range"`` (a signal outside its
    DBC range; ``values`` then holds the decoded SI values, ``signals`` the names out of range)
    or ``"unknown"`` (identifier not in the database).
    """

    def __init__(self, message: str, reason: str, values: dict[str, float | int] | None = None,
                 signals: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.reason = reason
        self.values = values
        self.signals = signals


class BusConfigError(CanError, ConfigError):
    """A bus configuration (interface, channel, bitrate, filters, ...) is invalid."""


class BusUnavailable(CanError):  # noqa: N818 -- name fixed by the CAN layer contract
    """The CAN bus cannot be opened, or the link is down and a frame could not be sent."""


class LogFileError(CanError, DataError):
    """A CAN log file cannot be read: missing, unsupported format, corrupt or truncated."""


class PayloadTooLongError(CanError, DataError, ValueError):
    """A udp_multicast datagram's ``data`` is a count of bytes above 64.

    python-can's ``can.Message(data=n)`` makes ``bytearray(n)``: a 20-byte datagram with
    ``data`` = 2**33 made the receiving process allocate 8 GiB before the frame check refused
    it. No CAN frame carries more than 64 bytes, so the bridge counts such a datagram as an
    invalid frame at once (:func:`clutch_ros.canbus.udp.malformed_reason`), without asking
    python-can.
    """
