"""The clutch interfaces, written once: topics and their QoS, ClutchEstimate fields, stamps, units.

Every layer reads these tables instead of spelling them again (ARCHITECTURE.md, "one concept,
one place"); the module imports only the standard library, so every layer may use it:

- :data:`TOPICS`: each clutch topic with its name as the nodes use it (relative, so a
  namespace applies; ``/diagnostics`` is absolute), its ROS 2 type, the QoS its publisher
  offers and the QoS a subscriber uses by default. ``nodes/qos.py`` builds the rclpy
  profiles from it, ``bag/writer.py`` the offered QoS a bag records, ``nodes/recorder.py``
  its default topic list, ``dashboard/topics.py`` the channels it serves.
- :data:`ESTIMATE_FIELDS`: every ``clutch_msgs/msg/ClutchEstimate`` field (the header aside),
  its unit and which model output fills it; the live node (``nodes/convert.py``) and
  ``clutch replay -o`` (``offline/replay.py``) both fill the message from it.
- Stamps: ``builtin_interfaces/Time`` is ``(sec, nanosec)``; bags store integer ns since the
  epoch; the model takes float seconds. :func:`stamp_to_s` is *the* conversion to seconds
  (the node's and the replay's, so both see bit-identical time steps).
- :data:`UNITS`: the unit spellings the importers (DBC signals, CSV column suffixes, MDF4 /
  CSV channel maps) accept, each with its quantity and conversion to SI (REP 103;
  temperatures in degrees Celsius, the unit of the RigState message).

QoS policies are written as rosbag2 writes them in ``metadata.yaml`` (and as ``ros2 topic``
spells them): ``reliable`` / ``best_effort``, ``volatile`` / ``transient_local``,
``keep_last`` / ``keep_all``, ``automatic``; a duration of None is infinite (the ROS default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

__all__ = [
    "BEST_EFFORT",
    "CAN_FRAMES",
    "CLUTCH_ESTIMATE",
    "DIAGNOSTICS",
    "ESTIMATE_FIELDS",
    "KEEP_ALL",
    "KEEP_LAST",
    "NS_PER_S",
    "PRESSURE_COMMAND",
    "PUMP_REQUEST",
    "RELIABLE",
    "RIG_STATE",
    "SENSOR_DATA",
    "SI_UNITS",
    "TOPICS",
    "TORQUE_REQUEST",
    "TRANSIENT_LOCAL",
    "UNITS",
    "VOLATILE",
    "EstimateField",
    "QosSpec",
    "Topic",
    "Unit",
    "estimate_fields",
    "fold_unit",
    "ns_to_s",
    "ns_to_stamp",
    "reliable",
    "s_to_ns",
    "s_to_stamp",
    "stamp_to_ns",
    "stamp_to_s",
    "topic",
    "unit_table",
]

# -- QoS ---------------------------------------------------------------------------------
RELIABLE, BEST_EFFORT = "reliable", "best_effort"
VOLATILE, TRANSIENT_LOCAL = "volatile", "transient_local"
KEEP_LAST, KEEP_ALL = "keep_last", "keep_all"


@dataclass(frozen=True)
class QosSpec:
    """A QoS profile as plain data (policy names as rosbag2's ``metadata.yaml`` has them).

    Attributes:
        reliability: ``reliable`` or ``best_effort``.
        durability: ``volatile`` or ``transient_local``.
        depth: history depth [messages] (``keep_last``).
        history: ``keep_last`` or ``keep_all`` (``unknown`` when a discovered publisher does
            not say: DDS discovery does not carry the history).
        deadline_ns, lifespan_ns, liveliness_lease_ns: [ns]; None is infinite (the default).
        liveliness: ``automatic`` (the default) or ``manual_by_topic``.

    """

    reliability: str = RELIABLE
    durability: str = VOLATILE
    depth: int = 10
    history: str = KEEP_LAST
    deadline_ns: int | None = None
    lifespan_ns: int | None = None
    liveliness: str = "automatic"
    liveliness_lease_ns: int | None = None

    def with_depth(self, depth: int) -> QosSpec:
        """Return this profile with history depth ``depth`` [messages]."""
        return replace(self, depth=int(depth))


def reliable(depth: int) -> QosSpec:
    """Return a reliable, volatile, keep-last ``depth`` profile (every clutch publisher)."""
    return QosSpec(RELIABLE, VOLATILE, int(depth))


#: ``rclpy.qos.qos_profile_sensor_data``: best effort, volatile, keep last 5. A subscriber
#: that needs only the latest sample; it receives from reliable publishers too (REP 2003).
SENSOR_DATA = QosSpec(BEST_EFFORT, VOLATILE, 5)


@dataclass(frozen=True)
class Topic:
    """One clutch topic.

    Attributes:
        name: as the nodes use it: relative (``rig_state``, resolved in the node's
            namespace) or absolute (``/diagnostics``).
        typename: ROS 2 type, ``pkg/msg/Name``.
        publisher: the QoS its publisher offers (what a bag records as offered).
        subscriber: the QoS a subscriber uses by default.
        publisher_node: the node that publishes it (``every node`` for ``/diagnostics``).
        description: one line.

    """

    name: str
    typename: str
    publisher: QosSpec
    subscriber: QosSpec
    publisher_node: str
    description: str

    @property
    def absolute(self) -> str:
        """The name in the root namespace (``/rig_state``), as ``ros2 bag record`` stores it."""
        return "/" + self.name.lstrip("/")


RIG_STATE = Topic(
    "rig_state", "clutch_msgs/msg/RigState", reliable(50), SENSOR_DATA, "can_bridge",
    "one rig sample, published on the trigger frame (0.25 s of history at 200 Hz); "
    "readers need only the latest")
CLUTCH_ESTIMATE = Topic(
    "clutch_estimate", "clutch_msgs/msg/ClutchEstimate", reliable(200), reliable(200),
    "estimator", "one estimate per accepted rig_state sample")
TORQUE_REQUEST = Topic(
    "torque_request", "clutch_msgs/msg/TorqueRequest", reliable(200), reliable(200),
    "demo_driver", "the torque asked of the clutch")
PRESSURE_COMMAND = Topic(
    "pressure_command", "clutch_msgs/msg/PressureCommand", reliable(200), reliable(200),
    "controller", "the controller's actuating-pressure command")
PUMP_REQUEST = Topic(
    "pump_request", "clutch_msgs/msg/PressureCommand", reliable(50), reliable(50),
    "can_bridge", "the command the bridge sent to the pump (after its gate), on change")
CAN_FRAMES = Topic(
    "can_frames", "clutch_msgs/msg/CanFrame", reliable(1000), reliable(1000), "can_bridge",
    "every rig CAN frame (bridge.publish_raw), 1 s of history")
DIAGNOSTICS = Topic(
    "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", reliable(10), reliable(10),
    "every node", "each node's status, 1 Hz")

#: Every clutch topic, in the order recorders list and dashboards advertise them.
TOPICS: tuple[Topic, ...] = (RIG_STATE, CLUTCH_ESTIMATE, TORQUE_REQUEST, PRESSURE_COMMAND,
                             PUMP_REQUEST, CAN_FRAMES, DIAGNOSTICS)
_BY_NAME = {t.name: t for t in TOPICS} | {t.absolute: t for t in TOPICS}


def topic(name: str) -> Topic | None:
    """Return the clutch topic named ``name``; None for any other name.

    ``name`` is relative or absolute (``rig_state`` or ``/rig_state``).
    """
    return _BY_NAME.get(name)


# -- ClutchEstimate ----------------------------------------------------------------------
class EstimateField(NamedTuple):
    """One ``clutch_msgs/msg/ClutchEstimate`` field.

    Attributes:
        name: message field name (a contract: never renamed).
        kind: ``float64``, ``float64[]`` (per lamella, rear to front), ``bool`` or ``string``.
        unit: SI unit (``1``: dimensionless; ``""``: none).
        source: ``estimate``: the model's ``Estimate`` / ``EstimateBatch`` attribute ``attr``;
            ``adaptation``: the ``AdaptationStatus`` attribute ``attr``; ``uncertainty``: the
            error model's output (:mod:`clutch_ros.model.uncertainty`), set by the caller.
        attr: the attribute of the source.
        state: for a bool filled from a state name: true when ``attr`` equals it
            (``adaptation_frozen``: ``state == "frozen"``); empty otherwise.

    """

    name: str
    kind: str
    unit: str
    source: str
    attr: str
    state: str = ""


def _est(name: str, kind: str, unit: str) -> EstimateField:
    return EstimateField(name, kind, unit, "estimate", name)


def _adapt(name: str, kind: str, unit: str, attr: str = "", state: str = "") -> EstimateField:
    return EstimateField(name, kind, unit, "adaptation", attr or name, state)


#: Every ClutchEstimate field (``header``, copied from the input RigState, aside), in
#: message order (``msg_defs/msg/ClutchEstimate.msg``).
ESTIMATE_FIELDS: tuple[EstimateField, ...] = (
    _est("modelled_torque", "float64", "N m"),
    EstimateField("modelled_torque_std", "float64", "N m", "uncertainty", "modelled_torque_std"),
    _est("reference_torque", "float64", "N m"),
    _est("measured_torque", "float64", "N m"),
    _est("torque_accuracy", "float64", "1"),
    _est("friction_coefficient", "float64", "1"),
    _est("lamella_normal_force", "float64[]", "N"),
    _est("spline_friction_force", "float64[]", "N"),
    _est("front_pressure", "float64", "Pa"),
    _est("rear_pressure", "float64", "Pa"),
    _est("pressure_difference", "float64", "Pa"),
    _est("slip_speed_filtered", "float64", "rad/s"),
    _est("spline_correction", "float64", "Pa"),
    _est("actuating_pressure", "float64", "Pa"),
    _est("lamella_temperature", "float64", "degC"),
    _est("spline_law", "string", ""),
    _est("overshoot", "bool", ""),
    _est("undershoot", "bool", ""),
    _adapt("friction_scale", "float64", "1"),
    _adapt("friction_scale_std", "float64", "1"),
    _adapt("spline_gain_scale", "float64", "1"),
    _adapt("spline_gain_scale_std", "float64", "1"),
    _adapt("adapting", "bool", ""),
    _adapt("adaptation_frozen", "bool", "", attr="state", state="frozen"),
)


def estimate_fields(source: str | None = None, kinds: tuple[str, ...] | None = None
                    ) -> tuple[str, ...]:
    """Return the names of the ClutchEstimate fields from ``source`` of the ``kinds`` given.

    None selects every source / kind; e.g. ``estimate_fields("estimate", ("float64",))``.
    """
    return tuple(f.name for f in ESTIMATE_FIELDS
                 if (source is None or f.source == source)
                 and (kinds is None or f.kind in kinds))


# -- stamps ------------------------------------------------------------------------------
#: Nanoseconds per second.
NS_PER_S = 1_000_000_000


def stamp_to_s(sec: Any, nanosec: Any) -> Any:
    """Return a stamp ``(sec, nanosec)`` in seconds [s]: ``sec + nanosec * 1e-9``.

    The one formula of the node and the replay (works element-wise on numpy arrays of
    float64), so both compute bit-identical time steps. Not correctly rounded: a float of
    seconds since the epoch resolves about 0.24 us anyway; exact time is :func:`stamp_to_ns`.
    """
    return sec + nanosec * 1e-9


def stamp_to_ns(sec: int, nanosec: int) -> int:
    """Return a stamp ``(sec, nanosec)`` in integer nanoseconds [ns] (exact)."""
    return int(sec) * NS_PER_S + int(nanosec)


def ns_to_stamp(ns: int) -> tuple[int, int]:
    """Return integer nanoseconds [ns] as ``(sec, nanosec)`` with ``0 <= nanosec < 1e9``.

    Exact; a negative time has a negative ``sec`` (-1 ns is ``(-1, 999999999)``).
    """
    return divmod(int(ns), NS_PER_S)


def ns_to_s(ns: int) -> float:
    """Return integer nanoseconds [ns] in seconds [s], correctly rounded."""
    return ns / NS_PER_S


def s_to_ns(seconds: float) -> int:
    """Return seconds [s] as integer nanoseconds [ns], rounded to the nearest (ties to even).

    Raises:
        ValueError: ``seconds`` is NaN or infinite.

    """
    if not math.isfinite(seconds):
        raise ValueError(f"time {seconds!r} s is not finite")
    return round(seconds * 1e9)


def s_to_stamp(seconds: float) -> tuple[int, int]:
    """Return seconds [s] as a ROS stamp ``(sec, nanosec)``, rounded to the nearest ns.

    NaN, infinite and negative times give ``(0, 0)``: a ROS time is never below zero.
    """
    if not math.isfinite(seconds) or seconds <= 0.0:
        return 0, 0
    return ns_to_stamp(round(seconds * 1e9))


# -- units -------------------------------------------------------------------------------
class Unit(NamedTuple):
    """A unit an importer accepts: ``si = value * scale + offset`` in :data:`SI_UNITS`.

    Attributes:
        symbol: canonical spelling (as in a DBC or a channel map).
        quantity: ``pressure``, ``temperature``, ``speed``, ``torque``, ``voltage``,
            ``current``, ``time`` or ``""`` (dimensionless: counters, states, flags).
        scale: factor to the SI unit of the quantity.
        offset: added after scaling (only ``K`` -> degC has one).
        aliases: other spellings of the same unit.

    """

    symbol: str
    quantity: str
    scale: float
    offset: float = 0.0
    aliases: tuple[str, ...] = ()


#: SI unit of each quantity (REP 103; temperatures in degrees Celsius, as the messages).
SI_UNITS = {"pressure": "Pa", "temperature": "degC", "speed": "rad/s", "torque": "N m",
            "voltage": "V", "current": "A", "time": "s", "": ""}

_RPM = 2.0 * math.pi / 60.0  # [rad/s per rpm]
_PSI = 6894.757293168361  # [Pa per psi]: 4.4482216152605 N / (0.0254 m)^2

#: Every accepted unit, by quantity.
UNITS: tuple[Unit, ...] = (
    Unit("Pa", "pressure", 1.0),
    Unit("kPa", "pressure", 1e3),
    Unit("MPa", "pressure", 1e6),
    Unit("bar", "pressure", 1e5),
    Unit("mbar", "pressure", 1e2),
    Unit("psi", "pressure", _PSI),
    Unit("degC", "temperature", 1.0, aliases=("°C", "C")),
    Unit("K", "temperature", 1.0, -273.15),
    Unit("rad/s", "speed", 1.0, aliases=("rads",)),
    Unit("rpm", "speed", _RPM, aliases=("1/min",)),
    Unit("N m", "torque", 1.0, aliases=("Nm", "N.m", "N*m")),
    Unit("kN m", "torque", 1e3, aliases=("kNm",)),
    Unit("V", "voltage", 1.0),
    Unit("mV", "voltage", 1e-3),
    Unit("A", "current", 1.0),
    Unit("mA", "current", 1e-3),
    Unit("s", "time", 1.0),
    Unit("ms", "time", 1e-3),
    Unit("us", "time", 1e-6),
    Unit("ns", "time", 1e-9),
    Unit("", "", 1.0),
)


def fold_unit(spelling: str) -> str:
    """Return the CSV-header form of a unit spelling (``rad/s`` -> ``rad_s``, ``N m`` -> ``nm``).

    Lower case, ``/`` as ``_``, no spaces, dots or stars, ``°`` as ``deg``.
    """
    out = spelling.replace("°", "deg").replace("/", "_")
    for char in " .*":
        out = out.replace(char, "")
    return out.lower()


def unit_table(quantity: str | None = None, *, fold: bool = False,
               offsets: bool = True) -> dict[str, Unit]:
    """Return spelling -> :class:`Unit` of every accepted spelling (symbol and aliases).

    Args:
        quantity: only this quantity (None: all).
        fold: key by :func:`fold_unit` (CSV column suffixes) instead of the exact spelling.
        offsets: include units with an offset (``K``); False for a converter that only
            scales (a DBC signal's unit).

    """
    out: dict[str, Unit] = {}
    for unit in UNITS:
        if (quantity is not None and unit.quantity != quantity) or \
                (not offsets and unit.offset):
            continue
        for spelling in (unit.symbol, *unit.aliases):
            out[fold_unit(spelling) if fold else spelling] = unit
    return out
