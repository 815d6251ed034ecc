"""The rosbags typestore of clutch_ros and builders for its messages.

One source of truth: the ``clutch_msgs`` types are parsed from the ``.msg`` files themselves
(``msg_defs/msg/*.msg`` in a source checkout, or ``share/clutch_msgs/msg`` of an installed
``clutch_msgs``), never from a copy in Python. They are registered on top of rosbags' store of
the ROS 2 distribution closest to Kilted (``Stores.ROS2_KILTED``; Jazzy with an older rosbags),
which provides ``std_msgs``, ``builtin_interfaces``, ``rosgraph_msgs`` (``/clock``) and
``diagnostic_msgs``.

Message builders take plain Python values: every field not given gets the ROS default
(0, 0.0, False, "", empty sequence, zero-filled fixed array). Stamps are integer nanoseconds
since the epoch (``stamp_ns``). Arrays accept lists, tuples, numpy arrays or (for ``uint8``)
bytes.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from clutch_ros import interfaces
from clutch_ros.bag.errors import BagError, MessageFieldError, UnknownTypeError
from clutch_ros.errors import ConfigError

__all__ = [
    "topic_name",
    "ADDED_FIELDS",
    "BASE_STORE",
    "CAN_FRAME_TYPE",
    "CLOCK_TYPE",
    "CLUTCH_ESTIMATE_TYPE",
    "CLUTCH_TYPES",
    "PRESSURE_COMMAND_TYPE",
    "RIG_STATE_TYPE",
    "TORQUE_REQUEST_TYPE",
    "Typestore",
    "can_frame_msg",
    "clutch_estimate_msg",
    "clutch_typestore",
    "find_msg_dir",
    "header_msg",
    "legacy_typestore",
    "make_msg",
    "msg_class",
    "ns_to_stamp",
    "pressure_command_msg",
    "rig_state_msg",
    "stamp_to_ns",
    "torque_request_msg",
]

PACKAGE = "clutch_msgs"
# the type names of the clutch topics (clutch_ros.interfaces.TOPICS), called *_TYPE so they
# are never mistaken for the interfaces' Topic records of the same topics
RIG_STATE_TYPE = interfaces.RIG_STATE.typename
CLUTCH_ESTIMATE_TYPE = interfaces.CLUTCH_ESTIMATE.typename
TORQUE_REQUEST_TYPE = interfaces.TORQUE_REQUEST.typename
PRESSURE_COMMAND_TYPE = interfaces.PRESSURE_COMMAND.typename
CAN_FRAME_TYPE = interfaces.CAN_FRAMES.typename
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
#: The clutch_msgs types the package relies on (more .msg files are registered if present).
CLUTCH_TYPES = (RIG_STATE_TYPE, CLUTCH_ESTIMATE_TYPE, TORQUE_REQUEST_TYPE, PRESSURE_COMMAND_TYPE,
                CAN_FRAME_TYPE)

#: rosbags store of the ROS 2 distribution closest to Kilted that this rosbags provides.
BASE_STORE: Stores = getattr(Stores, "ROS2_KILTED", Stores.ROS2_JAZZY)

_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1

# numpy dtypes of primitive array elements, as rosbags represents them.
_DTYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "octet": np.uint8,
    "int8": np.int8, "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16,
    "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
    "float32": np.float32, "float64": np.float64,
}  # fmt: skip
_FLOATS = {"float32", "float64"}


def _source_msg_dir() -> Path:
    """``msg_defs/msg`` of the source checkout this module was imported from."""
    return Path(__file__).resolve().parents[2] / "msg_defs" / "msg"


def _installed_msg_dirs() -> list[Path]:
    """``share/clutch_msgs/msg`` below every ament prefix (the ament index's search path).

    Never below Python's ``sys.prefix``: on a rig PC that is ``/usr``, not the colcon install.
    """
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return [Path(p) / "share" / PACKAGE / "msg" for p in prefixes]


def find_msg_dir(msg_dir: str | Path | None = None) -> Path:
    """Return the directory whose ``*.msg`` files define ``clutch_msgs``.

    Search order: ``msg_dir`` if given; ``msg_defs/msg`` of the source checkout (the files
    the interface package is built from); ``share/clutch_msgs/msg`` under each
    ``AMENT_PREFIX_PATH`` entry (a colcon install, or the venv ``tools/bootstrap.sh`` set up).

    Raises:
        BagError: no directory with ``.msg`` files was found.

    """
    candidates = (
        [Path(msg_dir)] if msg_dir is not None else [_source_msg_dir(), *_installed_msg_dirs()]
    )
    for cand in candidates:
        if cand.is_dir() and any(cand.glob("*.msg")):
            return cand.resolve()
    tried = ", ".join(str(c) for c in candidates)
    raise BagError(None, f"no clutch_msgs .msg files found (looked in {tried})")


#: Fields added to ``clutch_msgs`` types after bags were recorded with them: type -> names.
#: A bag recorded before a field existed still reads (:func:`legacy_typestore`; the
#: messages of such a bag lack the field).
ADDED_FIELDS: dict[str, tuple[str, ...]] = {
    CLUTCH_ESTIMATE_TYPE: ("modelled_torque_std",),
}


def _without_added(typename: str, text: str) -> str:
    """Return ``.msg`` text without the :data:`ADDED_FIELDS` of ``typename``."""
    drop = ADDED_FIELDS.get(typename, ())
    return "\n".join(line for line in text.splitlines()
                     if not (line.split("#", 1)[0].split()[1:2] and
                             line.split("#", 1)[0].split()[1] in drop))


@lru_cache(maxsize=8)
def _build_typestore(msg_dir: str, legacy: bool = False) -> Typestore:
    """Build (once per directory) the base store plus every ``.msg`` file in ``msg_dir``.

    ``legacy``: the types as they were before :data:`ADDED_FIELDS` were added.
    """
    store = get_typestore(BASE_STORE)
    types: dict[str, Any] = {}
    for path in sorted(Path(msg_dir).glob("*.msg")):
        typename = f"{PACKAGE}/msg/{path.stem}"
        try:
            text = path.read_text(encoding="utf-8")
            types.update(get_types_from_msg(_without_added(typename, text) if legacy else text,
                                            typename))
        except (OSError, UnicodeDecodeError, TypesysError) as err:
            raise BagError(path, f"cannot parse message definition: {err}") from err
    try:
        store.register(types)
    except TypesysError as err:
        raise BagError(msg_dir, f"cannot register clutch_msgs types: {err}") from err
    return store


@lru_cache(maxsize=1)
def _default_msg_dir() -> str:
    """Return the default ``.msg`` directory, searched once per process."""
    return str(find_msg_dir())


def clutch_typestore(msg_dir: str | Path | None = None) -> Typestore:
    """Return the (cached) rosbags typestore with every ``clutch_msgs`` type registered.

    Args:
        msg_dir: directory of ``*.msg`` files; default: see :func:`find_msg_dir` (searched
            once per process).

    """
    if msg_dir is None:
        return _build_typestore(_default_msg_dir())
    return _build_typestore(str(find_msg_dir(msg_dir)))


def legacy_typestore(msg_dir: str | Path | None = None) -> Typestore:
    """Return the typestore of the ``clutch_msgs`` types without their :data:`ADDED_FIELDS`.

    What bags recorded before those fields existed were written with; the reader decodes
    such a bag's topics with it when their recorded type hash matches it.
    """
    return _build_typestore(str(find_msg_dir(msg_dir)) if msg_dir is not None
                            else _default_msg_dir(), True)


def msg_class(typename: str, store: Typestore | None = None) -> type:
    """Return the rosbags message class of ``typename`` (e.g. ``clutch_msgs/msg/RigState``).

    Raises:
        UnknownTypeError: the type is not registered.

    """
    store = store or clutch_typestore()
    try:
        return store.types[typename]
    except KeyError:
        raise UnknownTypeError(
            None, f"unknown message type {typename!r}", typename=typename
        ) from None


def stamp_to_ns(stamp: Any) -> int:
    """Convert a ``builtin_interfaces/Time`` (rosbags or rclpy) to integer nanoseconds."""
    return interfaces.stamp_to_ns(stamp.sec, stamp.nanosec)


def ns_to_stamp(stamp_ns: int, store: Typestore | None = None) -> Any:
    """Convert integer nanoseconds since the epoch to a ``builtin_interfaces/Time``.

    Raises:
        MessageFieldError: the time does not fit ``int32`` seconds.

    """
    sec, nanosec = interfaces.ns_to_stamp(stamp_ns)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise MessageFieldError(None, f"stamp {stamp_ns} ns does not fit a ROS Time (int32 s)")
    return msg_class("builtin_interfaces/msg/Time", store)(sec=sec, nanosec=nanosec)


def header_msg(stamp_ns: int, frame_id: str = "", store: Typestore | None = None) -> Any:
    """Return a ``std_msgs/Header`` with ``stamp_ns`` [ns since epoch] and ``frame_id``."""
    return msg_class("std_msgs/msg/Header", store)(
        stamp=ns_to_stamp(stamp_ns, store), frame_id=str(frame_id)
    )


def _default(store: Typestore, desc: tuple) -> Any:
    """ROS default value of one field described by a rosbags field descriptor."""
    kind, args = desc
    if kind == Nodetype.BASE:
        name = args[0]
        if name == "string":
            return ""
        if name == "bool":
            return False
        return 0.0 if name in _FLOATS else 0
    if kind == Nodetype.NAME:
        return make_msg(args, store=store)
    sub, size = args
    if sub[0] == Nodetype.BASE and sub[1][0] in _DTYPES:
        return np.zeros(size if kind == Nodetype.ARRAY else 0, dtype=_DTYPES[sub[1][0]])
    return [_default(store, sub) for _ in range(size if kind == Nodetype.ARRAY else 0)]


def _coerce(store: Typestore, typename: str, field: str, desc: tuple, value: Any) -> Any:
    """Convert a plain Python value to what rosbags expects for this field."""
    kind, args = desc
    try:
        if kind == Nodetype.BASE:
            name = args[0]
            if name == "string":
                return str(value)
            if isinstance(value, str | bytes):
                raise TypeError(f"{type(value).__name__} for a {name} field")
            if name == "bool":
                return bool(value)
            return float(value) if name in _FLOATS else int(value)
        if kind == Nodetype.NAME:
            return make_msg(args, store=store, **value) if isinstance(value, dict) else value
        sub, size = args
        if sub[0] == Nodetype.BASE and sub[1][0] in _DTYPES:
            dtype = _DTYPES[sub[1][0]]
            arr: np.ndarray
            if isinstance(value, bytes | bytearray):
                arr = np.frombuffer(bytes(value), dtype=np.uint8).astype(dtype)
            else:
                arr = np.asarray(value, dtype=dtype).reshape(-1)
            if kind == Nodetype.ARRAY:
                if arr.size > size:
                    raise ValueError(f"{arr.size} elements for a fixed array of {size}")
                arr = np.concatenate([arr, np.zeros(size - arr.size, dtype=dtype)])
            elif size and arr.size > size:
                raise ValueError(f"{arr.size} elements for a sequence bounded to {size}")
            return arr
        return list(value)
    except (TypeError, ValueError, OverflowError) as err:
        raise MessageFieldError(None, f"{typename}.{field}: bad value {value!r}: {err}") from err


def make_msg(
    typename: str,
    stamp_ns: int | None = None,
    *,
    frame_id: str = "",
    store: Typestore | None = None,
    **fields: Any,
) -> Any:
    """Build a rosbags message of ``typename`` from plain Python values.

    Args:
        typename: ROS 2 type name, e.g. ``clutch_msgs/msg/RigState``.
        stamp_ns: header stamp [ns since epoch]; only for types with a ``header`` field
            (default 0 there). Ignored if ``header`` is passed explicitly.
        frame_id: header frame id (types with a ``header`` only).
        store: typestore (default :func:`clutch_typestore`).
        **fields: field values by name; missing fields get ROS defaults.

    Raises:
        UnknownTypeError: the type is not registered.
        MessageFieldError: an unknown field name or a value that cannot be converted.

    """
    store = store or clutch_typestore()
    cls, spec = _plan(store, typename)
    if not fields.keys() <= spec.keys():
        unknown = sorted(set(fields) - set(spec))
        raise MessageFieldError(None, f"{typename} has no field(s) {', '.join(unknown)}")
    values: dict[str, Any] = {}
    for name, (desc, is_header) in spec.items():
        if name in fields:
            values[name] = _coerce(store, typename, name, desc, fields[name])
        elif is_header:
            values[name] = header_msg(stamp_ns or 0, frame_id, store)
        else:
            values[name] = _default(store, desc)
    return cls(**values)


_PLANS: dict[tuple[int, str], tuple[Typestore, type, dict[str, tuple[tuple, bool]]]] = {}


def _plan(store: Typestore, typename: str) -> tuple[type, dict[str, tuple[tuple, bool]]]:
    """Class and field descriptors of ``typename`` (cached per store and type)."""
    key = (id(store), typename)
    hit = _PLANS.get(key)
    if hit is None or hit[0] is not store:
        cls = msg_class(typename, store)
        spec = {
            name: (desc, name == "header" and desc == (Nodetype.NAME, "std_msgs/msg/Header"))
            for name, desc in store.fielddefs[typename][1]
        }
        hit = _PLANS[key] = (store, cls, spec)
    return hit[1], hit[2]


def rig_state_msg(stamp_ns: int, *, frame_id: str = "", **fields: Any) -> Any:
    """Build a ``RigState``: pressure [Pa], temperatures [degC], speeds [rad/s], torque [N m].

    ``ff_voltages`` [V] and ``wheel_speeds`` [rad/s] accept any sequence.
    """
    return make_msg(RIG_STATE_TYPE, stamp_ns, frame_id=frame_id, **fields)


def clutch_estimate_msg(stamp_ns: int, *, frame_id: str = "", **fields: Any) -> Any:
    """Build a ``ClutchEstimate``: torques [N m], forces [N], pressures [Pa], speed [rad/s]."""
    return make_msg(CLUTCH_ESTIMATE_TYPE, stamp_ns, frame_id=frame_id, **fields)


def torque_request_msg(stamp_ns: int, torque: float, *, frame_id: str = "") -> Any:
    """Build a ``TorqueRequest`` for ``torque`` [N m]."""
    return make_msg(TORQUE_REQUEST_TYPE, stamp_ns, frame_id=frame_id, torque=torque)


def pressure_command_msg(stamp_ns: int, *, frame_id: str = "", **fields: Any) -> Any:
    """Build a ``PressureCommand``: ``pressure`` [Pa], torques [N m], ``limited``, ``reason``."""
    return make_msg(PRESSURE_COMMAND_TYPE, stamp_ns, frame_id=frame_id, **fields)


def can_frame_msg(
    stamp_ns: int, can_id: int, data: bytes = b"", *, frame_id: str = "", **fields: Any
) -> Any:
    """Build a ``CanFrame``; ``data`` (<= 8 bytes) is zero padded, ``dlc`` defaults to len."""
    fields.setdefault("dlc", len(data))
    return make_msg(CAN_FRAME_TYPE, stamp_ns, frame_id=frame_id, id=can_id, data=data, **fields)

def topic_name(name: str, namespace: str = "/") -> str:
    """Return the absolute topic name rosbag2 stores: ``rig_state`` -> ``/rig_state``.

    A relative ``name`` is resolved in ``namespace`` (``/rig1`` -> ``/rig1/rig_state``);
    an absolute one is returned unchanged.
    """
    name = name.strip()
    if not name or name in {"/", "~"}:
        raise ConfigError(f"invalid topic name {name!r}")
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"
