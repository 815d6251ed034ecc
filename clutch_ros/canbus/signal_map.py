"""The signal map: which DBC message and signal feeds each RigState field and the pump command.

A rig's own DBC has its own message and signal names, identifiers and scalings. The map says,
for every key, where its value comes from, as one string per key (the ``map.<key>`` node
parameters; ``params/rig_signal_map.yaml`` lists the default)::

    MESSAGE.SIGNAL                    SI = the DBC value converted by its unit
    MESSAGE.SIGNAL * SCALE            SI = SCALE * DBC value (unit ignored)
    MESSAGE.SIGNAL * SCALE + OFFSET   SI = SCALE * DBC value + OFFSET (e.g. K -> degC)
    (empty)                           not on this rig's bus

The DBC value is the signal's physical value (the DBC's factor and offset applied, in the
DBC's unit); without a ``SCALE`` its unit must be one of
:data:`clutch_ros.canbus.units.UNIT_TO_SI` and convert to the unit of the field (a pressure
field takes bar, kPa, psi ..., never rpm). Keys (:data:`KEYS`):

* every scalar RigState field (``actuating_pressure`` [Pa], ``lamella_temperature`` [degC],
  ...), ``has_measured_torque`` (a flag: non-zero is true; empty: true when the torque is
  finite) and ``slip_speed`` (empty: input minus output speed, the default);
* one key per array element, named like the CSV columns: ``ff_front_1`` ... ``ff_rear_4``
  [V], ``wheel_fl`` ... ``wheel_rr`` [rad/s];
* ``pump_pressure`` [Pa] and ``pump_state`` of the pump ECU's status (RigSample extras);
* ``pump_request``: the pump ECU's pressure request (its unit must be a pressure; the frame
  must be E2E protected as in ``params/rig.dbc``: attribute ``E2EChecksum``, signals
  ``*_Counter`` and ``*_Checksum``).

The default map is derived from :mod:`clutch_ros.rigstate` (``FIELDS[].dbc``, ``FF_SIGNALS``,
``WHEEL_SIGNALS``), the one place that names the signals of ``params/rig.dbc``.
:meth:`SignalMap.resolve` checks a map against a loaded DBC and raises
:class:`~clutch_ros.canbus.errors.DbcError` with one line naming the key and the missing
message or signal (or the unit that does not fit).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.errors import DbcError
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.rigstate import FF_SIGNALS, FIELDS, WHEEL_SIGNALS

__all__ = ["GROUPS", "KEYS", "REQUIRED_KEYS", "MapEntry", "ResolvedMap", "SignalMap",
           "Write"]

_FIELD = {f.name: f for f in FIELDS}
_ARRAY_KEYS = {f.name: f.csv_stems for f in FIELDS if f.kind == "array"}
_ARRAY_DEFAULTS = {"ff_voltages": [(m, s) for m, names in FF_SIGNALS for s in names],
                   "wheel_speeds": [(WHEEL_SIGNALS[0], s) for s in WHEEL_SIGNALS[1]]}
#: (key, message, signal) of the pump ECU's status extras and of the pump request
_EXTRAS = (("pump_pressure", "PumpStatus", "PumpSts_ActualPressure", "Pa"),
           ("pump_state", "PumpStatus", "PumpSts_State", ""))

#: key -> (target field, element index or None, SI unit, default spec); in message order
_TARGETS: dict[str, tuple[str, int | None, str, str]] = {}
for _f in FIELDS:
    if _f.kind == "array":
        for _i, (_key, (_m, _s)) in enumerate(zip(_ARRAY_KEYS[_f.name],
                                                  _ARRAY_DEFAULTS[_f.name], strict=True)):
            _TARGETS[_key] = (_f.name, _i, _f.unit, f"{_m}.{_s}")
    else:
        _TARGETS[_f.name] = (_f.name, None, _f.unit, ".".join(_f.dbc) if _f.dbc else "")
for _key, _m, _s, _unit in _EXTRAS:
    _TARGETS[_key] = (_key, None, _unit, f"{_m}.{_s}")
_TARGETS["pump_request"] = ("pump_request", None, "Pa",
                            f"{PumpRequestCodec.MESSAGE}.{PumpRequestCodec.PRESSURE}")

#: every map key, in RigState message order, then the pump extras and ``pump_request``
KEYS: tuple[str, ...] = tuple(_TARGETS)
#: keys that must be mapped: without them no RigState the estimator can use, or no pump
REQUIRED_KEYS = ("actuating_pressure", "lamella_temperature", "input_speed", "output_speed",
                 "pump_request")

#: stale-mask signal groups (bit order): (name, keys, required)
GROUPS: tuple[tuple[str, tuple[str, ...], bool], ...] = (
    ("pressure_torque", ("actuating_pressure", "measured_torque", "has_measured_torque"), True),
    ("shaft_speeds", ("input_speed", "output_speed", "slip_speed"), True),
    ("temperatures", ("lamella_temperature", "oil_temperature"), True),
    ("pump_status", ("pump_current", "pump_pressure", "pump_state"), True),
    ("ff_front", _ARRAY_KEYS["ff_voltages"][:4], False),
    ("ff_rear", _ARRAY_KEYS["ff_voltages"][4:], False),
    ("wheel_speeds", _ARRAY_KEYS["wheel_speeds"], False),
    ("torque_request", ("torque_request",), False),
)

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_SPEC = re.compile(rf"^\s*(?P<message>[A-Za-z_]\w*)\.(?P<signal>[A-Za-z_]\w*)\s*"
                   rf"(?:\*\s*(?P<scale>{_NUMBER}))?\s*"
                   rf"(?:(?P<sign>[-+])\s*(?P<offset>{_NUMBER}))?\s*$")


class MapEntry(NamedTuple):
    """One map entry: ``key`` fed by ``message.signal``, SI = scale * value + offset.

    ``scale`` None: converted by the DBC unit (``offset`` is then 0).
    """

    key: str
    message: str
    signal: str
    scale: float | None
    offset: float


class Write(NamedTuple):
    """A compiled entry: ``field[index]`` (or ``field``) = ``mult`` * decoded + ``offset``.

    ``decoded`` is the value :meth:`RigDatabase.decode` returns (already in SI for a known
    unit); ``mult`` turns it into the field's SI value.
    """

    key: str
    field: str
    # shadows tuple.index() on purpose (no caller uses that method on a Write)
    index: int | None  # type: ignore[assignment]
    signal: str
    mult: float
    offset: float


@dataclass(frozen=True)
class ResolvedMap:
    """A map checked against a DBC: what each frame writes, and the pump request codec.

    ``writes``: frame key -> the :class:`Write` entries of that frame; ``messages``: map key
    -> DBC message name (mapped keys only); ``pump``: :class:`PumpRequestCodec` for the mapped
    request (DBC maximum; the gate applies ``pump.max_pressure``).
    """

    writes: Mapping[int, tuple[Write, ...]]
    messages: Mapping[str, str]
    pump: PumpRequestCodec

    def group_messages(self, keys: Iterable[str]) -> tuple[str, ...]:
        """Return the DBC messages (sorted, unique) feeding any of ``keys``."""
        return tuple(sorted({self.messages[k] for k in keys if k in self.messages}))


class SignalMap:
    """A signal map ``{key: spec string}`` (see module docstring); unknown keys are refused.

    Missing keys take the default (``params/rig.dbc``). Raises :class:`DbcError` for an
    unknown key, a malformed spec or an empty required key.
    """

    def __init__(self, specs: Mapping[str, str] | None = None) -> None:
        specs = dict(specs or {})
        unknown = sorted(set(specs) - set(KEYS))
        if unknown:
            raise DbcError(f"signal map: unknown key(s) {', '.join(unknown)}; known: "
                           f"{', '.join(KEYS)}")
        self.specs = {key: str(specs.get(key, default)).strip()
                      for key, (_, _, _, default) in _TARGETS.items()}
        self.entries: dict[str, MapEntry] = {}
        for key, spec in self.specs.items():
            if not spec:
                if key in REQUIRED_KEYS:
                    raise DbcError(f"signal map: map.{key} is required (MESSAGE.SIGNAL)")
                continue
            match = _SPEC.match(spec)
            if match is None:
                raise DbcError(f"signal map: map.{key} = {spec!r} is not "
                               "'MESSAGE.SIGNAL [* SCALE] [+ OFFSET]'")
            scale = match["scale"]
            offset = float(match["offset"] or 0.0) * (-1.0 if match["sign"] == "-" else 1.0)
            if scale is None and offset:
                raise DbcError(f"signal map: map.{key} = {spec!r}: an offset needs a scale")
            entry = MapEntry(key, match["message"], match["signal"],
                             None if scale is None else float(scale), offset)
            if entry.scale is not None and not (math.isfinite(entry.scale) and entry.scale):
                raise DbcError(f"signal map: map.{key} = {spec!r}: scale must be finite, != 0")
            self.entries[key] = entry

    @classmethod
    def default(cls) -> SignalMap:
        """Return the map of ``params/rig.dbc`` (derived from :mod:`clutch_ros.rigstate`)."""
        return cls()

    @staticmethod
    def default_specs() -> dict[str, str]:
        """Return ``{key: spec}`` of the default map (``params/rig_signal_map.yaml``)."""
        return {key: default for key, (_, _, _, default) in _TARGETS.items()}

    def resolve(self, db: RigDatabase) -> ResolvedMap:
        """Check every entry against ``db``; return the compiled :class:`ResolvedMap`.

        Raises :class:`DbcError` naming the key and the missing message or signal, a unit
        that cannot be converted to the field's SI unit, or an unusable pump request.
        """
        writes: dict[int, list[Write]] = {}
        messages: dict[str, str] = {}
        for key, entry in self.entries.items():
            field, index, si_unit, _ = _TARGETS[key]
            where = f"signal map: map.{key} = {self.specs[key]!r}"
            try:
                frame = db.frame(entry.message)
            except DbcError:
                raise DbcError(f"{where}: no message {entry.message!r} in {db.path}") from None
            signals = {s.name: s for s in frame.signals}
            sig = signals.get(entry.signal)
            if sig is None:
                raise DbcError(f"{where}: message {entry.message} of {db.path} has no signal "
                               f"{entry.signal!r} (it has {', '.join(signals)})")
            messages[key] = entry.message
            if key == "pump_request":
                if entry.scale is not None:
                    raise DbcError(f"{where}: the pump request takes its scale from the DBC "
                                   "unit (bar, kPa, ...); no '* SCALE'")
                continue
            if entry.scale is None:
                if si_unit and (not sig.si_known or sig.si_unit != si_unit):
                    raise DbcError(f"{where}: unit {sig.unit!r} does not convert to "
                                   f"{si_unit}; write '{entry.message}.{entry.signal} * SCALE'")
                mult = 1.0
            else:
                mult = entry.scale / sig.factor
            writes.setdefault(frame.key, []).append(
                Write(key, field, index, entry.signal, mult, entry.offset))
        request = self.entries["pump_request"]
        try:
            pump = PumpRequestCodec(db, message=request.message, pressure=request.signal)
        except DbcError as err:
            raise DbcError(f"signal map: map.pump_request = {self.specs['pump_request']!r}: "
                           f"{err}") from None
        return ResolvedMap({k: tuple(v) for k, v in writes.items()}, messages, pump)
