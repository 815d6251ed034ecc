"""The RigState sample: its fields, units and every form it takes (one place).

A rig sample crosses the whole suite: decoded from CAN signals (``canbus``), published as the
ROS message ``clutch_msgs/msg/RigState`` (``nodes``), written to and read from bags as numpy
columns (``bag``), imported from CSV columns (``bag.csv_import``) and MDF4 channels. This
module is the one table that says which fields exist, in which SI unit (REP 103; temperatures
in °C), which CSV column stem and which signal of ``params/rig.dbc`` feed each, and the
conversions between the SI :class:`RigSample` and a message object. It imports nothing but
the standard library and :mod:`clutch_ros.interfaces` (stamps), so every layer may use it
(see ARCHITECTURE.md).

Field kinds:
    scalar  one float per sample (NaN when never received)
    flag    one bool (``has_measured_torque``)
    array   a fixed-order list (``ff_voltages``: front 1-4 then rear 1-4 [V];
            ``wheel_speeds``: FL, FR, RL, RR [rad/s]); empty when absent
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from clutch_ros.interfaces import s_to_stamp, stamp_to_s

__all__ = [
    "ARRAYS",
    "CSV_UNITS",
    "FIELDS",
    "FF_SIGNALS",
    "SCALARS",
    "WHEEL_SIGNALS",
    "FieldSpec",
    "RigSample",
    "fill_msg",
    "msg_fields",
    "sample_from_msg",
]


class FieldSpec(NamedTuple):
    """One RigState field.

    Attributes:
        name: message field name (a contract: never renamed).
        kind: ``scalar``, ``flag`` or ``array``.
        unit: SI unit of the message field (``degC`` for temperatures).
        quantity: physical quantity, which selects the unit conversions of an import
            (``pressure``, ``temperature``, ``speed``, ``torque``, ``voltage``, ``current``).
        csv_stems: CSV column stems that feed it (``pressure`` of ``pressure_bar``); an array
            field lists one stem per element, in order.
        dbc: ``(message, signal)`` of ``params/rig.dbc`` feeding a scalar, or None.

    """

    name: str
    kind: str
    unit: str
    quantity: str
    csv_stems: tuple[str, ...]
    dbc: tuple[str, str] | None


#: FlexiForce voltage signals of ``params/rig.dbc``, in ``ff_voltages`` order.
FF_SIGNALS = (("FlexiForceFront", ("FF_Front1", "FF_Front2", "FF_Front3", "FF_Front4")),
              ("FlexiForceRear", ("FF_Rear1", "FF_Rear2", "FF_Rear3", "FF_Rear4")))
#: Wheel speed signals of ``params/rig.dbc``, in ``wheel_speeds`` order.
WHEEL_SIGNALS = ("WheelSpeeds", ("WheelSpeedFL", "WheelSpeedFR", "WheelSpeedRL",
                                 "WheelSpeedRR"))

#: Every RigState data field (the header and ``stale_mask`` aside), in message order.
FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("actuating_pressure", "scalar", "Pa", "pressure", ("pressure",),
              ("RigFast", "ActuatingPressure")),
    FieldSpec("lamella_temperature", "scalar", "degC", "temperature", ("lamella_temp",),
              ("RigTemperatures", "LamellaTemperature")),
    FieldSpec("oil_temperature", "scalar", "degC", "temperature", ("oil_temp",),
              ("RigTemperatures", "OilTemperature")),
    FieldSpec("input_speed", "scalar", "rad/s", "speed", ("input_speed",),
              ("RigSpeed", "InputShaftSpeed")),
    FieldSpec("output_speed", "scalar", "rad/s", "speed", ("output_speed",),
              ("RigSpeed", "OutputShaftSpeed")),
    FieldSpec("slip_speed", "scalar", "rad/s", "speed", ("diff_speed",), None),
    FieldSpec("measured_torque", "scalar", "N m", "torque", ("torque",),
              ("RigFast", "MeasuredTorque")),
    FieldSpec("has_measured_torque", "flag", "", "", (), ("RigFast", "MeasuredTorqueValid")),
    FieldSpec("torque_request", "scalar", "N m", "torque", ("torque_request",),
              ("TorqueRequest", "TorqueRequest")),
    FieldSpec("ff_voltages", "array", "V", "voltage",
              tuple(f"ff_{side}_{i}" for side in ("front", "rear") for i in range(1, 5)), None),
    FieldSpec("wheel_speeds", "array", "rad/s", "speed",
              tuple(f"wheel_{w}" for w in ("fl", "fr", "rl", "rr")), None),
    FieldSpec("pump_current", "scalar", "A", "current", ("pump_current",),
              ("PumpStatus", "PumpSts_Current")),
)

#: Canonical CSV column unit suffix per quantity (``pressure`` -> ``pressure_bar``).
CSV_UNITS = {"pressure": "bar", "temperature": "c", "speed": "rpm", "torque": "nm",
             "voltage": "v", "current": "a"}

#: Names of the scalar (float) fields, in message order.
SCALARS = tuple(f.name for f in FIELDS if f.kind == "scalar")
#: Names of the array fields, in message order.
ARRAYS = tuple(f.name for f in FIELDS if f.kind == "array")

_NAN = float("nan")


@dataclass
class RigSample:
    """One RigState sample in SI units (see ``msg_defs/msg/RigState.msg``).

    Scalars never received are NaN (``torque_request`` 0.0). ``stamp`` [s] is the time of the
    newest contributing frame (None before any). ``stale_mask`` has bit i set for stale signal
    group i; ``stale`` names them; ``ages`` [s] per group (inf if never).
    ``pump_faults`` has bit i set for the i-th ``PumpSts_Flt*`` signal in DBC order.
    """

    stamp: float | None = None
    actuating_pressure: float = _NAN  # [Pa]
    lamella_temperature: float = _NAN  # [degC]
    oil_temperature: float = _NAN  # [degC]
    input_speed: float = _NAN  # [rad/s]
    output_speed: float = _NAN  # [rad/s]
    slip_speed: float = _NAN  # [rad/s] input_speed - output_speed
    measured_torque: float = _NAN  # [N m]
    has_measured_torque: bool = False
    torque_request: float = 0.0  # [N m]
    ff_voltages: list[float] = field(default_factory=list)  # [V] front 1-4, rear 1-4
    wheel_speeds: list[float] = field(default_factory=list)  # [rad/s] FL, FR, RL, RR
    pump_current: float = _NAN  # [A]
    stale_mask: int = 0
    stale: list[str] = field(default_factory=list)
    ages: dict[str, float] = field(default_factory=dict)  # [s]
    pump_pressure: float = _NAN  # [Pa] pump outlet pressure (PumpStatus)
    pump_state: int = -1  # PumpSts_State (0 Off, 1 Ready, 2 Active, 3 Degraded, 4 Fault)
    pump_faults: int = 0


def msg_fields(sample: Any) -> dict[str, Any]:
    """Return the RigState data fields of ``sample`` (any object with them) as plain values.

    Scalars become floats, arrays lists of floats, ``has_measured_torque`` is true only with a
    finite ``measured_torque``, and ``stale_mask`` is an int (0 when the object has none).
    The dict fills a rosbags message (``make_msg``) or an rclpy one (:func:`fill_msg`).
    """
    out: dict[str, Any] = {}
    for spec in FIELDS:
        value = getattr(sample, spec.name)
        if spec.kind == "scalar":
            out[spec.name] = float(value)
        elif spec.kind == "array":
            out[spec.name] = [float(v) for v in value]
    out["has_measured_torque"] = bool(sample.has_measured_torque
                                      and math.isfinite(out["measured_torque"]))
    out["stale_mask"] = int(getattr(sample, "stale_mask", 0))
    return out


def fill_msg(msg: Any, sample: Any, stamp_s: float, frame_id: str = "clutch") -> Any:
    """Fill the RigState message object ``msg`` (rclpy) from ``sample``; return ``msg``.

    The header stamp is ``stamp_s`` [s] split into ``sec``/``nanosec`` (rounded to the
    nearest ns; NaN or negative stamps give 0, which a ROS time cannot be below).
    """
    msg.header.stamp.sec, msg.header.stamp.nanosec = s_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    for name, value in msg_fields(sample).items():
        setattr(msg, name, value)
    return msg


def sample_from_msg(msg: Any) -> RigSample:
    """Return the :class:`RigSample` of a RigState message (rclpy or rosbags).

    ``stamp`` is the header stamp [s].
    """
    sample = RigSample(stamp=stamp_to_s(msg.header.stamp.sec, msg.header.stamp.nanosec))
    for spec in FIELDS:
        value = getattr(msg, spec.name)
        if spec.kind == "scalar":
            setattr(sample, spec.name, float(value))
        elif spec.kind == "array":
            setattr(sample, spec.name, [float(v) for v in value])
        else:
            setattr(sample, spec.name, bool(value))
    sample.stale_mask = int(msg.stale_mask)
    return sample
