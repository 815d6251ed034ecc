"""A table-driven decoder of the rig frames: the values of :meth:`RigDatabase.decode`, faster.

:meth:`clutch_ros.canbus.dbc.RigDatabase.decode` goes through cantools for every frame
(bitstruct, a conversion object per signal, two dictionaries). At 8,000 frames/s that was a
large share of the can_bridge's CPU. :class:`FastDecoder` compiles, once per frame of the
DBC, a table of ``(name, start bit, mask, sign bit, scale, offset, SI factor)`` and decodes a
payload with one ``int.from_bytes`` and a shift and mask per signal. The arithmetic is the
same as cantools' followed by the database's SI factor (``(raw * scale + offset) * factor``,
integers kept as integers where cantools keeps them), so the values are equal bit for bit
(``tests/canbus/test_fastdecode.py`` checks every frame of ``params/rig.dbc`` on random
payloads), and so are the errors (:class:`~clutch_ros.canbus.errors.FrameDecodeError` with
reason ``dlc``, ``checksum`` or ``range``, the values attached).

Only frames whose signals are all little-endian integers without multiplexing are compiled;
any other frame of a rig's own DBC (Motorola byte order, floats, multiplexed) is decoded by
:meth:`RigDatabase.decode` as before.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from clutch_ros.canbus.dbc import CAN_EFF_FLAG, RigDatabase, crc8_sae_j1850
from clutch_ros.canbus.errors import FrameDecodeError

__all__ = ["FastDecoder"]

#: (name, start bit, mask, sign bit (0: unsigned), scale, offset (None: identity), SI factor)
_Field = tuple[str, int, int, int, float, float | None, float]


def _conversion(signal: Any) -> tuple[float, float | None] | None:
    """Return ``(scale, offset)`` of a cantools signal's linear conversion.

    ``(1, None)`` for the identity, None when it is neither (the frame is not compiled).
    """
    conv = signal.conversion
    kind = type(conv).__name__
    if kind == "NamedSignalConversion":  # choices are not decoded: its inner conversion
        conv = getattr(conv, "_conversion", None)
        kind = type(conv).__name__
    if kind == "IdentityConversion" and not conv.is_float:
        return 1.0, None
    if kind in ("LinearConversion", "LinearIntegerConversion"):
        return conv.scale, conv.offset
    return None


def _compile(message: Any, factors: dict[str, float]) -> tuple[_Field, ...] | None:
    """Return the field table of a cantools message, or None when it cannot be compiled."""
    if message.is_multiplexed() or message.length > 64:
        return None
    fields = []
    for sig in message.signals:
        conversion = _conversion(sig)
        if (sig.byte_order != "little_endian" or sig.is_float or conversion is None
                or sig.start + sig.length > 8 * message.length):
            return None
        sign = 1 << (sig.length - 1) if sig.is_signed else 0
        fields.append((sig.name, sig.start, (1 << sig.length) - 1, sign, conversion[0],
                       conversion[1], factors.get(sig.name, 1.0)))
    return tuple(fields)


class FastDecoder:
    """Decode rig frames like :meth:`RigDatabase.decode` (see the module docstring).

    ``db``: the database; :meth:`decode` takes a frame key (:func:`frame_key`) of it.
    ``compiled``: the keys decoded from the table (the others go to ``db.decode``).
    """

    def __init__(self, db: RigDatabase) -> None:
        self.db = db
        self._tables: dict[int, tuple[str, int, tuple[_Field, ...], bool,
                                      tuple[tuple[str, float, float], ...]]] = {}
        for spec in db.frames:
            message, factors, ranges = db.decode_tables(spec.key)
            fields = _compile(message, dict(factors))
            if fields is not None:
                self._tables[spec.key] = (spec.name, spec.length, fields,
                                          spec.checksum_signal is not None, ranges)
        self.compiled = frozenset(self._tables)
        self._slow: Callable[..., dict[str, float | int]] = db.decode

    def table(self, key: int) -> tuple[str, int, tuple[_Field, ...], bool,
                                       tuple[tuple[str, float, float], ...]] | None:
        """Return frame ``key``'s decoding table (None: decoded by cantools).

        ``(name, length, fields, e2e, ranges)``; each field ``(signal, start bit, mask, sign
        bit, scale, offset or None, factor)``, each range ``(signal, minimum, maximum)`` [SI]:
        what :meth:`decode` applies, for a compiled twin of it
        (:mod:`clutch_ros.canbus.intake`).
        """
        return self._tables.get(key)

    def decode(self, key: int, data: bytes | bytearray) -> dict[str, float | int]:
        """Return ``{signal: SI value}`` of a payload of frame ``key`` (a DBC frame).

        Raises :class:`FrameDecodeError` as :meth:`RigDatabase.decode` does (reasons
        ``unknown``, ``dlc``, ``checksum``, ``payload``, ``range``).
        """
        table = self._tables.get(key)
        if table is None:
            return self._slow(key & ~CAN_EFF_FLAG, data, bool(key & CAN_EFF_FLAG))
        name, length, fields, e2e, ranges = table
        if len(data) != length:
            raise FrameDecodeError(f"{name}: DLC {len(data)} bytes, expected {length}", "dlc")
        if e2e and crc8_sae_j1850(data[1:]) != data[0]:
            raise FrameDecodeError(f"{name}: checksum 0x{data[0]:02X}, expected "
                                   f"0x{crc8_sae_j1850(data[1:]):02X}", "checksum")
        bits = int.from_bytes(data, "little")
        out: dict[str, float | int] = {}
        for sig, start, mask, sign, scale, offset, factor in fields:
            raw = (bits >> start) & mask
            if raw & sign:
                raw -= sign << 1
            value = raw if offset is None else raw * scale + offset
            out[sig] = value * factor if factor != 1.0 else value
        for sig, lo, hi in ranges:
            if not lo <= out[sig] <= hi:
                bad = tuple(n for n, lo_, hi_ in ranges if not lo_ <= out[n] <= hi_)
                text = ", ".join(f"{n} = {out[n]:g}" for n in bad)
                raise FrameDecodeError(f"{name}: {text} outside the DBC range", "range",
                                       values=out, signals=bad)
        return out
