"""The PumpRequest frame: the pressure command to the pump ECU, E2E protected.

:class:`PumpRequestCodec` encodes a pressure [Pa] and a rolling counter into the frame
(checksum computed) and decodes one back. The frame is encoded by the can_bridge 100 times a
second on its PumpRequest cycle: where the DBC lays it out as on ``params/rig.dbc`` (a
checksum in byte 0, a 4-bit counter and an unsigned little-endian integer pressure, nothing
else), the payload is built directly: the pressure's raw value from cantools' own conversion
(``numeric_scaled_to_raw``, so the same rounding), shifted into place with the counter, and
the checksum over bytes 1..7. That is what :meth:`RigDatabase.encode
<clutch_ros.canbus.dbc.RigDatabase.encode>` gives through cantools' generic packing (a fifth
of its cost; ``tests/canbus/test_pump_codec.py`` compares both on every pressure step). Any
other layout goes through :meth:`RigDatabase.make_message
<clutch_ros.canbus.dbc.RigDatabase.make_message>`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import can

from clutch_ros.canbus.dbc import (
    FrameSpec,
    RigDatabase,
    crc8_sae_j1850,
    finite_value,
    format_frame_key,
    frame_key,
)
from clutch_ros.canbus.errors import DbcError, EncodeError, FrameDecodeError
from clutch_ros.errors import ConfigError

__all__ = ["PumpRequestCodec"]


def _direct_layout(db: RigDatabase, spec: FrameSpec, pressure: str,
                   factor: float) -> tuple[Callable[[float], int], float, int, int, int] | None:
    """Return ``(to_raw, SI factor, pressure start bit, its mask, counter start)`` or None.

    None unless the frame is a checksum in bits 0..7, a counter of 4 bits and ``pressure``,
    all little-endian unsigned integers with an identity or linear conversion.
    """
    message = db.decode_tables(spec.key)[0]
    signals = {sig.name: sig for sig in message.signals}
    if message.is_multiplexed() or spec.length != 8 or set(signals) != {
            spec.checksum_signal, spec.counter_signal, pressure}:
        return None
    if any(sig.byte_order != "little_endian" or sig.is_signed or sig.is_float
           or type(sig.conversion).__name__ not in ("IdentityConversion", "LinearConversion",
                                                    "LinearIntegerConversion")
           for sig in signals.values()):
        return None
    check, count, value = (signals[spec.checksum_signal], signals[spec.counter_signal],
                           signals[pressure])
    if (check.start, check.length) != (0, 8) or count.length != 4 \
            or type(count.conversion).__name__ != "IdentityConversion" \
            or value.start + value.length > 64 or count.start + 4 > 64 \
            or not _disjoint(check, count, value):
        return None
    return (value.conversion.numeric_scaled_to_raw, factor, value.start, (1 << value.length) - 1,
            count.start)


def _disjoint(*signals: Any) -> bool:
    """Return True when the signals' bit ranges do not overlap."""
    used = 0
    for sig in signals:
        bits = ((1 << sig.length) - 1) << sig.start
        if used & bits:
            return False
        used |= bits
    return True


class PumpRequestCodec:
    """Encode and verify the E2E-protected ``PumpRequest`` frame (pressure in Pa).

    ``max_pressure`` [Pa] is the largest pressure :meth:`encode` accepts (default: the DBC
    maximum of ``PumpReq_Pressure``, 60 bar); it must not exceed the DBC maximum.
    ``resolution`` is 100 Pa (0.001 bar). Raises :class:`clutch_ros.errors.ConfigError` for a
    bad ``max_pressure``. ``message`` and ``pressure`` name the frame and its pressure signal
    (defaults: ``PumpRequest.PumpReq_Pressure`` of ``params/rig.dbc``); the signal's unit must
    convert to Pa.
    """

    MESSAGE = "PumpRequest"
    PRESSURE = "PumpReq_Pressure"

    def __init__(self, db: RigDatabase | None = None, max_pressure: float | None = None,
                 message: str | None = None, pressure: str | None = None) -> None:
        self.db = db if db is not None else RigDatabase()
        self.MESSAGE, self.PRESSURE = message or self.MESSAGE, pressure or self.PRESSURE
        self.spec = self.db.frame(self.MESSAGE)
        if not self.spec.e2e or self.spec.counter_signal is None:
            raise DbcError(f"{self.db.path}: {self.MESSAGE} is not E2E protected")
        sig = self.db.signal(self.PRESSURE)
        if sig.si_unit != "Pa" or sig.name not in {s.name for s in self.spec.signals}:
            raise DbcError(f"{self.db.path}: {self.MESSAGE}.{self.PRESSURE} must be a pressure "
                           f"signal of {self.MESSAGE} (unit bar, kPa, ...), has {sig.unit!r}")
        if sig.maximum is None or sig.minimum != 0.0:
            raise DbcError(f"{self.db.path}: {self.PRESSURE} must have the range [0|max]")
        self.resolution = sig.resolution
        dbc_max = sig.maximum
        if max_pressure is None:
            max_pressure = dbc_max
        if not (math.isfinite(max_pressure) and 0.0 < max_pressure <= dbc_max + 1e-6):
            raise ConfigError(
                f"pump max pressure must be in (0, {dbc_max:.0f}] Pa, got {max_pressure!r}"
            )
        #: largest raw value that does not exceed ``max_pressure``
        self.max_raw = math.floor(max_pressure / self.resolution + 1e-9)
        #: largest encodable pressure [Pa] (``max_pressure`` rounded down to the resolution)
        self.max_pressure = self.max_raw * self.resolution
        self._layout = _direct_layout(self.db, self.spec, self.PRESSURE, sig.factor)

    def quantize(self, pressure: float) -> float:
        """Return the representable pressure [Pa] nearest to ``pressure``, within [0, max].

        NaN maps to 0 Pa.
        """
        if math.isnan(pressure):
            return 0.0
        if pressure >= self.max_pressure:
            return self.max_pressure
        raw = max(0, min(self.max_raw, round(pressure / self.resolution)))
        return raw * self.resolution

    def encode(self, pressure: float, counter: int, timestamp: float = 0.0) -> can.Message:
        """Return a PumpRequest frame for ``pressure`` [Pa] and rolling ``counter`` (0..15).

        The pressure is rounded to the 100 Pa resolution; the checksum is computed. Strict:
        NaN/inf, negative or above ``max_pressure`` (beyond half a resolution step) and
        counters outside 0..15 raise :class:`EncodeError`.
        """
        value = finite_value(pressure, "pump pressure")
        if value < 0.0 or value > self.max_pressure + 0.5 * self.resolution:
            raise EncodeError(
                f"pump pressure {value:.1f} Pa outside [0, {self.max_pressure:.0f}] Pa"
            )
        quantized = self.quantize(value)
        layout = self._layout
        if layout is None or isinstance(counter, bool) or not isinstance(counter, int) \
                or not 0 <= counter <= 15:  # (the database's path raises for a bad counter)
            return self.db.make_message(
                self.MESSAGE, {self.PRESSURE: quantized}, counter=counter, timestamp=timestamp
            )
        to_raw, factor, p_start, mask, c_start = layout
        raw = to_raw(quantized / factor)
        if not 0 <= raw <= mask:  # (a DBC range wider than its field: cantools says why)
            return self.db.make_message(
                self.MESSAGE, {self.PRESSURE: quantized}, counter=counter, timestamp=timestamp
            )
        bits = (raw << p_start) | (counter << c_start)
        data = bytearray(bits.to_bytes(self.spec.length, "little"))
        data[0] = crc8_sae_j1850(data[1:])
        return can.Message(arbitration_id=self.spec.frame_id, is_extended_id=self.spec.is_extended,
                           data=data, timestamp=timestamp)

    def decode(self, frame: can.Message | bytes | bytearray) -> tuple[float, int, bool]:
        """Decode a PumpRequest into ``(pressure [Pa], counter, checksum_ok)``.

        Raises :class:`FrameDecodeError` when ``frame`` is a message with another identifier
        or the payload has the wrong length.
        """
        if isinstance(frame, can.Message):
            if (
                frame.is_error_frame
                or frame.is_remote_frame
                or frame_key(frame.arbitration_id, frame.is_extended_id) != self.spec.key
            ):
                raise FrameDecodeError(
                    f"not a {self.MESSAGE} frame: {format_frame_key(frame.arbitration_id)}",
                    "unknown",
                )
            data = bytes(frame.data)
        else:
            data = bytes(frame)
        values = self.db.decode(  # the receiver judges checksum and range itself
            self.spec.frame_id, data, self.spec.is_extended, check_e2e=False, check_range=False
        )
        checksum_ok = crc8_sae_j1850(data[1:]) == data[0]
        assert self.spec.counter_signal is not None
        return float(values[self.PRESSURE]), int(values[self.spec.counter_signal]), checksum_ok
