"""Conversions to rclpy messages: model estimates, CAN rig samples and raw frames.

:class:`CdrCodec` reads and writes the serialised (CDR) form of flat message types without
building a message object: the estimator takes ``rig_state`` raw and publishes its
``ClutchEstimate`` as bytes (:class:`EstimateEncoder`), a third of its per-sample cost in
the node layer (``RigState`` deserialised about 14 us, ``ClutchEstimate`` converted in
``publish`` about 7 us; the codec's read and write a few us each).
"""

from __future__ import annotations

import math
import struct
from array import array

import numpy as np
from clutch_msgs.msg import CanFrame, ClutchEstimate, RigState

from clutch_ros.interfaces import ESTIMATE_FIELDS, s_to_stamp
from clutch_ros.nodes.stamps import sec_to_stamp
from clutch_ros.rigstate import RigSample, msg_fields

__all__ = ["CdrCodec", "EstimateEncoder", "EstimateMessage", "RigStateEncoder",
           "can_frame_to_ros"]


#: (message field, Estimate attribute) of the per-lamella arrays
_ARRAYS = tuple((f.name, f.attr) for f in ESTIMATE_FIELDS if f.kind == "float64[]")


def _field_expr(f) -> str:
    """Python expression of ClutchEstimate field ``f`` from ``est``, ``status``, ``std``."""
    # identifiers of the constant table only, never data
    assert f.name.isidentifier() and f.attr.isidentifier(), f
    assert not f.state or f.state.isidentifier(), f
    if f.source == "uncertainty":
        return "float(std)"
    value = f"{'est' if f.source == 'estimate' else 'status'}.{f.attr}"
    if f.state:
        value = f"{value} == {f.state!r}"
    convert = {"float64": "float", "bool": "bool", "string": "str", "float64[]": ""}
    return f"{convert[f.kind]}({value})" if convert[f.kind] else value


def _compile_scalar_filler():
    """Return ``fill(msg, est, status)`` setting every scalar field of the table.

    The table is compiled once into straight-line assignments (``msg.modelled_torque =
    float(est.modelled_torque)`` ...): a loop of ``setattr``/``getattr`` over it cost about
    twice the hand-written assignments, 5-10 us per estimate on the node's hot path.
    """
    lines = ["def fill(msg, est, status):"]
    for f in ESTIMATE_FIELDS:
        if f.kind == "float64[]" or f.source == "uncertainty":  # set by the node itself
            continue
        lines.append(f"    msg.{f.name} = {_field_expr(f)}")
    namespace: dict = {}
    exec("\n".join(lines), namespace)
    return namespace["fill"]


_fill_scalars = _compile_scalar_filler()


class EstimateMessage:
    """One preallocated ``clutch_msgs/ClutchEstimate``, refilled for every published estimate.

    The fields and where each comes from are :data:`clutch_ros.interfaces.ESTIMATE_FIELDS`
    (the table ``clutch replay -o`` writes from too). Building a ClutchEstimate per sample
    cost more than publishing it (the constructor alone about 40 µs, the per-lamella lists
    another 13 µs); this keeps one message and copies the model's per-lamella arrays [N]
    into numpy views of the message's own ``array('d')`` buffers. Safe because rclpy's
    ``publish`` serialises the message before it returns: refill it only after the previous
    ``publish`` call returned (one thread).
    """

    def __init__(self, msg_type):
        """Preallocate one ``msg_type`` (``ClutchEstimate``) message."""
        self.msg = msg_type()
        self._views: dict[str, np.ndarray] = {}  # numpy views on the message arrays [N]
        self._lamellas = -1

    def _resize(self, n: int) -> None:
        """Give the message float64 arrays of ``n`` lamellas (at start, or a new count)."""
        for name, _ in _ARRAYS:
            setattr(self.msg, name, array("d", bytes(8 * n)))
            # a view of the array the message holds (its setter may store a copy)
            self._views[name] = np.frombuffer(getattr(self.msg, name), dtype=np.float64)
        self._lamellas = n

    def fill(self, est, status, header, torque_std=math.nan):
        """Fill the message from a model ``Estimate`` and ``AdaptationStatus``; return it.

        ``header`` (the input RigState's) is referenced, not copied: the estimate carries the
        stamp of the sample it was computed from. ``torque_std``: ``modelled_torque_std``
        [N m] (:class:`clutch_ros.model.uncertainty.TorqueStd`).
        """
        msg = self.msg
        n = len(est.lamella_normal_force)
        if n != self._lamellas:
            self._resize(n)
        views = self._views
        for name, attr in _ARRAYS:
            views[name][:] = getattr(est, attr)
        msg.header = header
        _fill_scalars(msg, est, status)
        msg.modelled_torque_std = float(torque_std)
        return msg


class RigStateEncoder:
    """The serialised ``RigState`` of a rig sample, without a message object.

    For ``Publisher.publish(bytes)`` on the can_bridge's receive thread: the message that
    :func:`clutch_ros.rigstate.fill_msg` fills (the fields of
    :func:`clutch_ros.rigstate.msg_fields`, the one RigState mapping), written by one
    :class:`CdrCodec` call instead of building an rclpy message (its constructor and
    ``setattr`` of 19 fields) that ``publish`` then converts again.
    """

    HEADER = ("header.stamp.sec", "header.stamp.nanosec", "header.frame_id")

    def __init__(self, msg_type=RigState):
        """Compile for ``msg_type`` (ValueError if its fields are not msg_fields' plus a header)."""
        self.codec = CdrCodec(msg_type)
        names = self.codec.names
        self._order = names[len(self.HEADER):]
        if names[:len(self.HEADER)] != self.HEADER \
                or set(self._order) != set(msg_fields(RigSample())):
            raise ValueError(f"{msg_type.__name__} fields {names} are not a header and "
                             f"msg_fields' {sorted(msg_fields(RigSample()))}")

    def encode(self, sample, stamp_s: float, frame_id: str = "clutch") -> bytes:
        """Return the RigState of ``sample`` stamped ``stamp_s`` [s] (as :func:`fill_msg`)."""
        fields = msg_fields(sample)
        sec, nanosec = s_to_stamp(stamp_s)
        return self.codec.encode(sec, nanosec, frame_id, *[fields[n] for n in self._order])


def can_frame_to_ros(frame, offset: float = 0.0):
    """Return a ``CanFrame`` of a python-can frame (payload cut/padded to 8 bytes)."""
    msg = CanFrame()
    sec_to_stamp(frame.timestamp + offset, msg.header.stamp)
    msg.id, msg.is_rtr = frame.arbitration_id, frame.is_remote_frame
    msg.is_extended, msg.is_error = frame.is_extended_id, frame.is_error_frame
    msg.dlc = min(frame.dlc, 255)
    msg.data = list(bytes(frame.data[:8]).ljust(8, b"\0"))
    return msg


#: ROS IDL primitive -> struct format character (CDR sizes: bool and octets 1 byte)
_PRIMITIVES = {"double": "d", "float": "f", "boolean": "?", "octet": "B", "uint8": "B",
               "int8": "b", "char": "B", "int16": "h", "uint16": "H", "int32": "i",
               "uint32": "I", "int64": "q", "uint64": "Q"}
_DTYPES = {"d": "f8", "f": "f4", "?": "?", "B": "u1", "b": "i1", "h": "i2", "H": "u2",
           "i": "i4", "I": "u4", "q": "i8", "Q": "u8"}
_ZEROS = tuple(bytes(n) for n in range(8))  # padding


def _leaves(msg_type, prefix: str = "") -> list[tuple[str, str]]:
    """``(dotted name, kind)`` of every leaf of ``msg_type`` in CDR order.

    kind: a struct character (a primitive), ``"s"`` (a string) or ``"[c"`` (an unbounded
    sequence of primitive ``c``). TypeError for what the codec does not handle (arrays,
    bounded sequences or strings, sequences of messages, wide strings).
    """
    out: list[tuple[str, str]] = []
    for name, typ in msg_type.get_fields_and_field_types().items():
        inner = typ[len("sequence<"):-1] if typ.startswith("sequence<") else None
        if typ in _PRIMITIVES:
            out.append((prefix + name, _PRIMITIVES[typ]))
        elif typ == "string":
            out.append((prefix + name, "s"))
        elif inner in _PRIMITIVES:
            out.append((prefix + name, "[" + _PRIMITIVES[inner]))
        elif "/" in typ and inner is None and "[" not in typ:
            out += _leaves(type(getattr(msg_type(), name)), f"{prefix}{name}.")
        else:
            raise TypeError(f"{msg_type.__name__}.{name}: {typ} is not supported by CdrCodec")
    return out


def _segments(leaves: list[tuple[str, str]]) -> list[tuple[str, list[int]]]:
    """Group the leaves into runs of primitives, strings and sequences.

    ``("run", indices)``: primitives read by one struct; ``("s", [i])``: a string;
    ``("[c", [i])``: a sequence of primitive ``c``.

    A run starts anew at a primitive aligned wider than the run's first one, so that every
    padding inside a run is fixed once the run's start is aligned (CDR aligns each primitive
    to its size, relative to the payload after the 4-byte encapsulation header).
    """
    segs: list[tuple[str, list[int]]] = []
    for i, (_name, kind) in enumerate(leaves):
        if kind in ("s",) or kind.startswith("["):
            segs.append((kind, [i]))
        elif segs and segs[-1][0] == "run" \
                and struct.calcsize(kind) <= struct.calcsize(leaves[segs[-1][1][0]][1]):
            segs[-1][1].append(i)
        else:
            segs.append(("run", [i]))
    return segs


def _run_format(leaves, idx: list[int]) -> str:
    """Return the struct format (no byte order) of a run of primitives with its inner padding."""
    fmt, pos = "", 0
    for i in idx:
        c = leaves[i][1]
        size = struct.calcsize(c)
        pad = -pos % size
        fmt += "x" * pad + c
        pos += pad + size
    return fmt


class CdrCodec:
    """CDR (XCDR1, as Fast DDS writes ROS 2 messages) of a flat message type, compiled once.

    ``decode(raw)`` returns the values of every leaf field (:attr:`names`, nested messages
    flattened: ``header.stamp.sec``), sequences as tuples; ``encode(*values)`` returns the
    serialised message (little endian) of values in that order, sequences as anything
    numpy takes. Both are straight-line code generated from the message's field types, so
    a changed ``.msg`` changes the codec with it (tests/nodes/test_convert_cdr.py checks
    both ways against rclpy's own serialisation).
    """

    def __init__(self, msg_type):
        """Compile the codec of ``msg_type`` (TypeError if a field is not supported)."""
        self.msg_type = msg_type
        leaves = _leaves(msg_type)
        self.names = tuple(name for name, _ in leaves)
        segs = _segments(leaves)
        namespace: dict = {"_Z": _ZEROS, "_np": np, "_unpack_from": struct.unpack_from,
                           "_u32le": struct.Struct("<I"),
                           "_u32be": struct.Struct(">I")}
        decoders = []
        for order, tag in (("<", "le"), (">", "be")):
            decoders.append(self._decoder(leaves, segs, order, tag, namespace))
        enc = self._encoder(leaves, segs, namespace)
        exec("\n\n".join([*decoders, enc]), namespace)  # generated from the type, never data
        self._be, self._le = namespace["decode_be"], namespace["decode_le"]
        self.encode = namespace["encode"]

    def decode(self, raw: bytes) -> tuple:
        """Values of every leaf of the serialised message ``raw`` (:attr:`names` order)."""
        return (self._le if raw[1] & 1 else self._be)(raw)

    @staticmethod
    def _decoder(leaves, segs, order: str, tag: str, namespace: dict) -> str:
        lines = [f"def decode_{tag}(raw):", "    p = 4"]
        for k, (kind, idx) in enumerate(segs):
            names = ", ".join(f"v{i}" for i in idx)
            if kind == "run":
                st = struct.Struct(order + _run_format(leaves, idx))
                namespace[f"_s{k}{tag}"] = st
                align = struct.calcsize(leaves[idx[0]][1])
                if align > 1:
                    lines.append(f"    p += -(p - 4) % {align}")
                lines += [f"    {names}, = _s{k}{tag}.unpack_from(raw, p)",
                          f"    p += {st.size}"]
                continue
            lines += ["    p += -(p - 4) % 4", f"    n, = _u32{tag}.unpack_from(raw, p)",
                      "    p += 4"]
            if kind == "s":
                lines += [f"    {names} = raw[p:p + n - 1].decode()", "    p += n"]
            else:
                size = struct.calcsize(kind[1])
                lines += [f"    if n: p += -(p - 4) % {size}",
                          f"    {names} = _unpack_from(f'{order}{{n}}{kind[1]}', raw, p) "
                          "if n else ()",
                          f"    p += n * {size}"]
        lines.append(f"    return ({', '.join(f'v{i}' for i in range(len(leaves)))},)")
        return "\n".join(lines)

    @staticmethod
    def _encoder(leaves, segs, namespace: dict) -> str:
        args = ", ".join(f"v{i}" for i in range(len(leaves)))
        lines = [f"def encode({args}):", "    b = bytearray(b'\\x00\\x01\\x00\\x00')"]
        for k, (kind, idx) in enumerate(segs):
            if kind == "run":
                st = struct.Struct("<" + _run_format(leaves, idx))
                namespace[f"_e{k}"] = st
                align = struct.calcsize(leaves[idx[0]][1])
                if align > 1:
                    lines.append(f"    b += _Z[-(len(b) - 4) % {align}]")
                lines.append(f"    b += _e{k}.pack({', '.join(f'v{i}' for i in idx)})")
                continue
            i = idx[0]
            if kind == "s":
                lines += [f"    s = v{i}.encode()", "    b += _Z[-(len(b) - 4) % 4]",
                          "    b += _u32le.pack(len(s) + 1)", "    b += s", "    b += _Z[1]"]
            else:
                size = struct.calcsize(kind[1])
                lines += [f"    n = len(v{i})", "    b += _Z[-(len(b) - 4) % 4]",
                          "    b += _u32le.pack(n)",
                          f"    if n: b += _Z[-(len(b) - 4) % {size}]",
                          f"    b += _np.asarray(v{i}, '<{_DTYPES[kind[1]]}').tobytes()"]
        lines.append("    return bytes(b)")
        return "\n".join(lines)


class EstimateEncoder:
    """The serialised ``ClutchEstimate`` of a model estimate, without a message object.

    For ``Publisher.publish(bytes)``: the fields and their sources are those of
    :class:`EstimateMessage` (:data:`clutch_ros.interfaces.ESTIMATE_FIELDS`), written by one
    :class:`CdrCodec` call from straight-line code generated from that table.
    """

    def __init__(self, msg_type=ClutchEstimate):
        """Compile for ``msg_type`` (ValueError if its fields are not the table's, in order)."""
        self.codec = CdrCodec(msg_type)
        header = ("header.stamp.sec", "header.stamp.nanosec", "header.frame_id")
        expected = header + tuple(f.name for f in ESTIMATE_FIELDS)
        if self.codec.names != expected:
            raise ValueError(f"{msg_type.__name__} fields {self.codec.names} are not "
                             f"ESTIMATE_FIELDS' {expected}")
        args = ", ".join(["sec", "nanosec", "frame_id", *map(_field_expr, ESTIMATE_FIELDS)])
        namespace: dict = {"_encode": self.codec.encode}
        exec(f"def encode(est, status, sec, nanosec, frame_id, std):\n"
             f"    return _encode({args})", namespace)  # from the constant table, never data
        self.encode = namespace["encode"]
        """``encode(est, status, sec, nanosec, frame_id, torque_std)``: the message's bytes.

        ``est``: a model ``Estimate``; ``status``: its ``AdaptationStatus``; ``sec``,
        ``nanosec``, ``frame_id``: the header (the input RigState's); ``torque_std``:
        ``modelled_torque_std`` [N m].
        """
