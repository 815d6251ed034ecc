"""The rig's CAN database: strict DBC loading, SI decoding and encoding, E2E protection.

The DBC (``params/rig.dbc``) carries bus units (bar, rpm, Nm, degC, V, A). This module is
the one place where they are converted to and from SI, with the factors of
:data:`clutch_ros.canbus.units.UNIT_TO_SI` (``si = factor * bus``). A rig's own DBC may use
units outside that table: loaded with ``strict_units=False`` such signals keep their bus
value (factor 1, :attr:`SignalSpec.si_known` False) and a signal map must give their scale.

Frames whose message attribute ``E2EChecksum`` is ``CRC8_SAE_J1850`` carry a 4-bit rolling
counter (signal ``*_Counter``) and an 8-bit checksum in byte 0 (signal ``*_Checksum``): CRC-8
SAE J1850 (polynomial 0x1D, initial value 0xFF, final XOR 0xFF, not reflected) over payload
bytes 1..DLC-1. :func:`crc8_sae_j1850` implements it (check value of ``b"123456789"``: 0x4B).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import cantools
import cantools.database

from clutch_ros.canbus.errors import DbcError, EncodeError, FrameDecodeError
from clutch_ros.canbus.units import UNIT_TO_SI
from clutch_ros.config.presets import DBC_NAME, share_file

__all__ = [
    "CAN_EFF_FLAG", "UNIT_TO_SI", "FrameSpec", "RigDatabase", "SignalSpec", "counter_gap",
    "crc8_sae_j1850", "default_dbc_path", "finite_value", "format_frame_key", "frame_key",
]

#: Flag or-ed into a frame key for 29-bit identifiers (the SocketCAN ``CAN_EFF_FLAG``).
CAN_EFF_FLAG = 0x80000000

_E2E_ATTRIBUTE = "E2EChecksum"
_E2E_CRC8 = "CRC8_SAE_J1850"


def _make_crc8_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8_TABLE = _make_crc8_table()


def crc8_table() -> tuple[int, ...]:
    """Return the 256-entry table of :func:`crc8_sae_j1850` (for compiled code)."""
    return _CRC8_TABLE


def crc8_sae_j1850(data: bytes | bytearray) -> int:
    """Return the CRC-8 SAE J1850 of ``data`` (poly 0x1D, init 0xFF, xorout 0xFF), 0..255."""
    crc = 0xFF
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc ^ 0xFF


def counter_gap(previous: int, current: int, modulo: int = 16) -> int:
    """Return how many frames were lost between two rolling-counter values (0 = consecutive).

    A repeated counter (``current == previous``) counts as ``modulo - 1`` lost frames; a
    4-bit counter cannot see more than 15 consecutive losses.
    """
    return (current - previous - 1) % modulo


def finite_value(value: Any, what: str) -> float:
    """Return ``float(value)``; a non-number or NaN/inf raises :class:`EncodeError`."""
    try:
        number = float(value)
    except (TypeError, ValueError) as err:
        raise EncodeError(f"{what}: not a number: {value!r}") from err
    if not math.isfinite(number):
        raise EncodeError(f"{what}: value {number} is not finite")
    return number


def frame_key(arbitration_id: int, is_extended: bool = False) -> int:
    """Return the key identifying a frame: the id, or-ed with :data:`CAN_EFF_FLAG` if 29-bit."""
    return arbitration_id | CAN_EFF_FLAG if is_extended else arbitration_id


def format_frame_key(key: int) -> str:
    """Format a frame key like Vector ASC: ``0x100`` or ``0x18EBFF00x`` for 29-bit ids."""
    if key & CAN_EFF_FLAG:
        return f"0x{key & ~CAN_EFF_FLAG:08X}x"
    return f"0x{key:03X}"


def default_dbc_path() -> Path:
    """Return the path of the rig DBC ``params/rig.dbc`` (:func:`~.presets.share_file`).

    The source checkout's, or the installed package's found through the ament index.
    """
    return share_file(DBC_NAME)


@dataclass(frozen=True)
class SignalSpec:
    """One DBC signal with its SI conversion.

    ``factor`` converts bus to SI (``si = factor * bus``); ``minimum``/``maximum`` and
    ``resolution`` are in SI units (``si_unit``); ``unit`` is the DBC unit. ``si_known`` is
    False for a unit outside :data:`UNIT_TO_SI` (then ``si_unit`` is the DBC unit, factor 1).
    """

    name: str
    unit: str
    si_unit: str
    factor: float
    minimum: float | None
    maximum: float | None
    resolution: float
    choices: Mapping[int, str]
    si_known: bool = True


@dataclass(frozen=True)
class FrameSpec:
    """One DBC message: identifier, length [bytes], cycle time [s] and its signals."""

    name: str
    frame_id: int
    is_extended: bool
    length: int
    cycle_time: float | None
    signals: tuple[SignalSpec, ...]
    counter_signal: str | None
    checksum_signal: str | None

    @property
    def key(self) -> int:
        """Frame key (see :func:`frame_key`)."""
        return frame_key(self.frame_id, self.is_extended)

    @property
    def e2e(self) -> bool:
        """True when the frame carries a CRC-8 checksum (and a rolling counter)."""
        return self.checksum_signal is not None


class RigDatabase:
    """The rig CAN database, loaded strictly, decoding to and encoding from SI values.

    ``path`` defaults to :func:`default_dbc_path`. Raises :class:`DbcError` naming the file
    when it is missing, does not parse strictly, uses a unit outside :data:`UNIT_TO_SI`
    (unless ``strict_units`` is False), or an E2E frame lacks its checksum (8 bits at bit 0)
    or counter signal.
    """

    def __init__(self, path: str | Path | None = None, strict_units: bool = True) -> None:
        self.path = Path(path) if path is not None else default_dbc_path()
        self.strict_units = strict_units
        try:
            self._db = cantools.database.load_file(str(self.path), strict=True)
        except FileNotFoundError as err:
            raise DbcError(f"{self.path}: DBC file not found") from err
        except (OSError, UnicodeDecodeError) as err:
            raise DbcError(f"{self.path}: cannot read DBC file: {err}") from err
        except Exception as err:  # cantools raises ParseError, ValueError, KeyError, ...
            raise DbcError(f"{self.path}: invalid DBC: {err}") from err
        if not isinstance(self._db, cantools.database.can.Database):
            raise DbcError(f"{self.path}: not a CAN database")
        self._by_key: dict[int, FrameSpec] = {}
        self._by_name: dict[str, FrameSpec] = {}
        self._messages: dict[int, cantools.database.can.Message] = {}
        self._factors: dict[int, tuple[tuple[str, float], ...]] = {}
        self._ranges: dict[int, tuple[tuple[str, float, float], ...]] = {}
        self._signals: dict[str, SignalSpec] = {}
        self._frame_signals: dict[int, dict[str, SignalSpec]] = {}  # encode's lookup
        for message in self._db.messages:
            spec = self._make_spec(message)
            self._by_key[spec.key] = spec
            self._by_name[spec.name] = spec
            self._messages[spec.key] = message
            self._factors[spec.key] = tuple(
                (sig.name, sig.factor) for sig in spec.signals if sig.factor != 1.0
            )
            for sig in spec.signals:
                self._signals[sig.name] = sig
            self._frame_signals[spec.key] = {sig.name: sig for sig in spec.signals}
            # [min, max] in SI, widened by half a resolution step against rounding; a DBC
            # range of [0|0] means "none"
            self._ranges[spec.key] = tuple(
                (sig.name, sig.minimum - 0.5 * sig.resolution, sig.maximum + 0.5 * sig.resolution)
                for sig in spec.signals if sig.minimum is not None and sig.maximum is not None
                and not sig.minimum == sig.maximum == 0.0)

    def _make_spec(self, message: cantools.database.can.Message) -> FrameSpec:
        signals = []
        for sig in message.signals:
            unit = sig.unit or ""
            if unit not in UNIT_TO_SI and self.strict_units:
                raise DbcError(
                    f"{self.path}: signal {message.name}.{sig.name} has unit {unit!r}; "
                    f"known units: {sorted(UNIT_TO_SI)}"
                )
            si_unit, factor = UNIT_TO_SI.get(unit, (unit, 1.0))
            signals.append(
                SignalSpec(
                    name=sig.name,
                    unit=unit,
                    si_unit=si_unit,
                    factor=factor,
                    minimum=None if sig.minimum is None else sig.minimum * factor,
                    maximum=None if sig.maximum is None else sig.maximum * factor,
                    resolution=abs(sig.scale) * factor,
                    choices={int(k): str(v) for k, v in (sig.choices or {}).items()},
                    si_known=unit in UNIT_TO_SI,
                )
            )
        counter = next((s.name for s in message.signals if s.name.endswith("_Counter")), None)
        checksum: str | None = None
        attr = message.dbc.attributes.get(_E2E_ATTRIBUTE) if message.dbc else None
        scheme = attr.value if attr is not None else None
        if isinstance(scheme, int) and attr is not None:
            choices = attr.definition.choices or []
            scheme = choices[scheme] if 0 <= scheme < len(choices) else None
        if scheme == _E2E_CRC8:
            checksum_sig = next(
                (s for s in message.signals if s.name.endswith("_Checksum")), None
            )
            if (checksum_sig is None or checksum_sig.start != 0 or checksum_sig.length != 8
                    or counter is None):
                raise DbcError(
                    f"{self.path}: E2E message {message.name} needs an 8-bit *_Checksum "
                    "signal at bit 0 and a *_Counter signal"
                )
            checksum = checksum_sig.name
        cycle = message.cycle_time
        return FrameSpec(
            name=message.name,
            frame_id=message.frame_id,
            is_extended=bool(message.is_extended_frame),
            length=message.length,
            cycle_time=cycle / 1000.0 if cycle else None,
            signals=tuple(signals),
            counter_signal=counter,
            checksum_signal=checksum,
        )

    # -- lookup ---------------------------------------------------------------------------

    @property
    def frames(self) -> tuple[FrameSpec, ...]:
        """All frames of the database, in DBC order."""
        return tuple(self._by_name.values())

    @property
    def keys(self) -> frozenset[int]:
        """Frame keys (see :func:`frame_key`) of all frames in the database."""
        return frozenset(self._by_key)

    def lookup(self, arbitration_id: int, is_extended: bool = False) -> FrameSpec | None:
        """Return the frame with this identifier, or None when it is not in the database."""
        return self._by_key.get(frame_key(arbitration_id, is_extended))

    def frame(self, name: str) -> FrameSpec:
        """Return the frame called ``name``; raises :class:`DbcError` when there is none."""
        try:
            return self._by_name[name]
        except KeyError:
            raise DbcError(f"{self.path}: no message named {name!r}") from None

    def signal(self, name: str) -> SignalSpec:
        """Return the signal called ``name`` (in any frame); raises :class:`DbcError`."""
        try:
            return self._signals[name]
        except KeyError:
            raise DbcError(f"{self.path}: no signal named {name!r}") from None

    def decode_tables(self, key: int) -> tuple[Any, tuple[tuple[str, float], ...],
                                               tuple[tuple[str, float, float], ...]]:
        """Return frame ``key``'s cantools message, SI factors and SI ranges."""
        return self._messages[key], self._factors[key], self._ranges[key]

    # -- decoding -------------------------------------------------------------------------

    def decode(
        self,
        arbitration_id: int,
        data: bytes | bytearray,
        is_extended: bool = False,
        check_e2e: bool = True,
        check_range: bool = True,
    ) -> dict[str, float | int]:
        """Decode a payload of a known frame into ``{signal: SI value}``.

        Values are in SI (see the module table); counters, checksums, states and flags stay
        integers (choices are not converted to strings). Raises :class:`FrameDecodeError`
        with ``reason`` ``"unknown"`` (id not in the DBC), ``"dlc"`` (length differs from
        the DBC), ``"checksum"`` (E2E checksum wrong; not checked when ``check_e2e`` is
        False), ``"payload"`` or ``"range"`` (a value outside its signal's DBC range, e.g. a
        lamella temperature of -326 degC for a signal defined on -40..320; not checked when
        ``check_range`` is False; the error carries the decoded ``values``).
        """
        key = frame_key(arbitration_id, is_extended)
        spec = self._by_key.get(key)
        if spec is None:
            raise FrameDecodeError(f"{format_frame_key(key)}: not in the DBC", "unknown")
        if len(data) != spec.length:
            raise FrameDecodeError(
                f"{spec.name}: DLC {len(data)} bytes, expected {spec.length}", "dlc"
            )
        if check_e2e and spec.checksum_signal is not None and crc8_sae_j1850(data[1:]) != data[0]:
            raise FrameDecodeError(
                f"{spec.name}: checksum 0x{data[0]:02X}, expected "
                f"0x{crc8_sae_j1850(data[1:]):02X}",
                "checksum",
            )
        try:
            values = self._messages[key].decode(
                bytes(data), decode_choices=False, scaling=True, allow_excess=False
            )
        except Exception as err:  # cantools DecodeError, ValueError, ...
            raise FrameDecodeError(f"{spec.name}: cannot decode: {err}", "payload") from err
        out: dict[str, float | int] = dict(values)  # type: ignore[arg-type]
        for name, factor in self._factors[key]:
            out[name] = out[name] * factor
        bad = check_range and tuple(n for n, lo, hi in self._ranges[key] if not lo <= out[n] <= hi)
        if bad:
            text = ", ".join(f"{n} = {out[n]:g}" for n in bad)
            raise FrameDecodeError(f"{spec.name}: {text} outside the DBC range", "range",
                                   values=out, signals=bad)
        return out

    def decode_message(self, msg: can.Message) -> tuple[FrameSpec, dict[str, float | int]]:
        """Decode a python-can data frame; returns its spec and ``{signal: SI value}``.

        Raises :class:`FrameDecodeError` like :meth:`decode` (also for error/remote frames,
        reason ``"unknown"``).
        """
        if msg.is_error_frame or msg.is_remote_frame:
            raise FrameDecodeError("error and remote frames carry no signals", "unknown")
        values = self.decode(msg.arbitration_id, msg.data, msg.is_extended_id)
        return self._by_key[frame_key(msg.arbitration_id, msg.is_extended_id)], values

    # -- encoding -------------------------------------------------------------------------

    def encode(
        self, name: str, values: Mapping[str, float], counter: int | None = None,
        strict: bool = True,
    ) -> bytes:
        """Encode SI ``values`` (every signal of frame ``name``) into its payload.

        For E2E frames the checksum is computed here (do not pass it) and the counter is
        taken from ``counter`` (0..15) unless ``values`` holds it. Raises
        :class:`EncodeError` for unknown or missing signals, NaN/inf, values outside the DBC
        range and bad counters. ``strict=False`` skips cantools' range check (a third of the
        cost of a frame): only for a caller that has clamped every value into its DBC range
        itself, as the simulated rig does 2,400 times a second (``RigCanPort``).
        """
        spec = self.frame(name)
        message = self._messages[spec.key]
        bus_values: dict[str, float] = {}
        given = dict(values)
        if spec.checksum_signal is not None:
            if spec.checksum_signal in given:
                raise EncodeError(f"{name}: the checksum is computed, do not pass it")
            given[spec.checksum_signal] = 0
        if counter is not None:
            if spec.counter_signal is None:
                raise EncodeError(f"{name}: has no rolling counter")
            given[spec.counter_signal] = counter
        if spec.counter_signal is not None and spec.counter_signal in given:
            cnt = given[spec.counter_signal]
            if isinstance(cnt, bool) or not isinstance(cnt, int) or not 0 <= cnt <= 15:
                raise EncodeError(f"{name}: counter must be an int 0..15, got {cnt!r}")
        own = self._frame_signals[spec.key]
        for sig_name, value in given.items():
            sig = own.get(sig_name)
            if sig is None:
                raise EncodeError(f"{name}: unknown signal {sig_name!r}")
            number = finite_value(value, f"{name}.{sig_name}")
            bus_values[sig_name] = number / sig.factor if sig.factor != 1.0 else value
        try:
            data = bytearray(message.encode(bus_values, scaling=True, strict=strict))
        except KeyError as err:
            raise EncodeError(f"{name}: missing signal {err}") from err
        except Exception as err:  # cantools EncodeError, ValueError
            raise EncodeError(f"{name}: {err}") from err
        if spec.checksum_signal is not None:
            data[0] = crc8_sae_j1850(data[1:])
        return bytes(data)

    def make_message(
        self,
        name: str,
        values: Mapping[str, float],
        counter: int | None = None,
        timestamp: float = 0.0,
        strict: bool = True,
    ) -> can.Message:
        """Encode frame ``name`` like :meth:`encode` and wrap it into a :class:`can.Message`.

        ``timestamp`` [s] is copied into the message (bus time base).
        """
        spec = self.frame(name)
        return can.Message(
            arbitration_id=spec.frame_id,
            is_extended_id=spec.is_extended,
            data=self.encode(name, values, counter, strict),
            timestamp=timestamp,
        )
