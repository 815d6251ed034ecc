"""Whole streams of one message type as numpy columns: fast writing and generic reading.

Writing millions of messages one rosbags object at a time (build, ``serialize_cdr``) costs
~15 us per message. When every message of a stream has the same CDR layout (same sequence
lengths and strings, as for a rig run's ``RigState`` or an estimator's ``ClutchEstimate``),
:class:`TemplateSerializer` serializes one template message and patches the field bytes of
a whole block of messages with numpy; the bytes equal what ``serialize_cdr`` gives for each
message (tested), at a fraction of the cost.

Reading: :func:`read_columns` decodes every message of one topic of any type the
:class:`~clutch_ros.bag.columns.ColumnDecoder` supports (strings are skipped) into columns,
through the checked :class:`~clutch_ros.bag.reader.BagReader` (count check included).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype

from clutch_ros.bag.columns import _PRIM, ColumnDecoder, CorruptMessageError
from clutch_ros.bag.diagnose import blame_file
from clutch_ros.bag.errors import BagCorruptError, BagError, MessageFieldError
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.typestore import (
    ADDED_FIELDS,
    Typestore,
    clutch_typestore,
    make_msg,
    topic_name,
)
from clutch_ros.bag.writer import BagWriter
from clutch_ros.interfaces import NS_PER_S

__all__ = ["TemplateSerializer", "read_columns", "write_columns"]

_BLOCK = 65536


class TemplateSerializer:
    """Serialize blocks of messages of one fixed layout by patching a template's bytes.

    Args:
        typename: ROS 2 type, e.g. ``clutch_msgs/msg/ClutchEstimate``.
        store: typestore (default :func:`~clutch_ros.bag.typestore.clutch_typestore`).
        frame_id: header frame id of every message (types with a header).
        **fields: template field values fixing the layout: every sequence at the length all
            messages will have (``lamella_normal_force=np.zeros(8)``), every string at its
            value (``spline_law="ff_t"``). Numeric values are overwritten per message.

    Raises:
        MessageFieldError: unknown fields, or a type the column layout does not support.

    """

    def __init__(
        self, typename: str, *, store: Typestore | None = None, frame_id: str = "", **fields: Any
    ):
        self.typename = typename
        self.store = store or clutch_typestore()
        template = make_msg(typename, 0, frame_id=frame_id, store=self.store, **fields)
        raw = bytes(self.store.serialize_cdr(template, typename))
        try:
            decoder = ColumnDecoder(self.store, typename)
        except ValueError as err:
            raise MessageFieldError(None, f"{typename}: {err}") from err
        self.template = np.frombuffer(raw, dtype=np.uint8)
        self.size = len(raw)
        self.offsets = decoder.offsets(raw)
        lengths = decoder.decode([raw])
        #: field path -> (little-endian dtype, elements per message)
        self.fields: dict[str, tuple[np.dtype, int]] = {}
        for step in decoder.steps:
            kind, path = step[0], step[1]
            if kind == "string":
                continue
            dtype = np.dtype(_PRIM[step[2]])
            width = 1 if kind == "prim" else step[3] if kind == "array" else 0
            if kind == "seq":
                width = int(lengths[f"{path}.len"][0])
            self.fields[path] = (dtype, width)

    def serialize(self, n: int, columns: Mapping[str, Any]) -> np.ndarray:
        """Return an ``(n, size)`` uint8 array: ``n`` messages with ``columns`` patched in.

        Args:
            n: number of messages.
            columns: field path (``header.stamp.sec``, ``modelled_torque``...) -> values of
                shape ``(n,)`` (scalars; a Python scalar broadcasts) or ``(n, width)``
                (sequences and arrays). Fields not given keep the template's value.

        Raises:
            MessageFieldError: unknown field, or values of the wrong shape.

        """
        block = np.tile(self.template, (n, 1))
        for name, values in columns.items():
            spec = self.fields.get(name)
            if spec is None:
                raise MessageFieldError(
                    None, f"{self.typename} has no numeric field {name!r} of fixed layout"
                )
            dtype, width = spec
            arr = np.asarray(values)
            if dtype.kind == "f" and arr.dtype.kind not in "fiub":
                raise MessageFieldError(None, f"{self.typename}.{name}: not numbers")
            try:
                arr = np.broadcast_to(arr, (n,) if width == 1 and arr.ndim <= 1 else (n, width))
            except ValueError as err:
                raise MessageFieldError(
                    None,
                    f"{self.typename}.{name}: values of shape {np.shape(values)} do not fit "
                    f"{n} messages of {width} element(s)",
                ) from err
            arr = np.ascontiguousarray(arr.reshape(n, width), dtype=dtype)
            off = self.offsets[name]
            block[:, off : off + width * dtype.itemsize] = arr.view(np.uint8)
        return block

    def serialize_stamped(self, stamps_ns: np.ndarray, columns: Mapping[str, Any]) -> np.ndarray:
        """Like :meth:`serialize` with ``header.stamp`` set from ``stamps_ns`` [ns]."""
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        cols = dict(columns)
        cols["header.stamp.sec"] = stamps // NS_PER_S
        cols["header.stamp.nanosec"] = stamps % NS_PER_S
        return self.serialize(len(stamps), cols)


def write_columns(
    writer: BagWriter,
    topic: str,
    serializer: TemplateSerializer,
    stamps_ns: np.ndarray,
    columns: Mapping[str, Any],
    bag_ns: np.ndarray | None = None,
) -> int:
    """Write one message per stamp: header stamp ``stamps_ns`` [ns], ``columns`` patched in.

    Args:
        writer: an open writer with ``topic`` added (of the serializer's type).
        topic: topic name.
        serializer: the layout.
        stamps_ns: header stamps [ns since epoch].
        columns: see :meth:`TemplateSerializer.serialize` (rows aligned with ``stamps_ns``).
        bag_ns: bag (receive) timestamps [ns]; default: the header stamps.

    Returns:
        the number of messages written.

    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    times = stamps if bag_ns is None else np.asarray(bag_ns, dtype=np.int64)
    size = serializer.size
    cols = {k: np.asarray(v) for k, v in columns.items()}
    write = writer.write_raw
    for first in range(0, len(stamps), _BLOCK):
        last = min(first + _BLOCK, len(stamps))
        part = {k: (v[first:last] if v.ndim else v) for k, v in cols.items()}
        data = memoryview(serializer.serialize_stamped(stamps[first:last], part).tobytes())
        for i, stamp in enumerate(times[first:last].tolist()):
            write(topic, stamp, data[i * size : (i + 1) * size])
    return len(stamps)


def read_columns(
    path: str | Path,
    topic: str,
    *,
    store: Typestore | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, str]]:
    """Decode every message of ``topic`` into columns (strings: the first message's value).

    Returns:
        ``(columns, bag_time_ns, strings)``: columns by dotted field path (see
        :class:`~clutch_ros.bag.columns.ColumnDecoder`), plus ``stamp_ns`` (header stamp,
        int64 ns) for types with a header; bag timestamps [ns]; the string fields of the
        first message (``{"spline_law": "ff_t", "header.frame_id": "rig"}``).

    Raises:
        BagError: topic missing, or a type the column decoder does not support; plus
            everything :meth:`~clutch_ros.bag.reader.BagReader.messages` raises.

    """
    with BagReader(path, store=store) as bag:
        name = topic_name(topic)
        conns = bag._select(name)
        typename = conns[0].msgtype
        for conn in conns:
            bag._check_type(conn)
        store_ = bag.store_for(conns[0])  # an older definition (typestore.ADDED_FIELDS)
        try:
            decoder = ColumnDecoder(store_, typename)
        except ValueError as err:
            raise BagError(bag.path, f"{name}: cannot read {typename} as columns: {err}") from err
        raws: list[bytes] = []
        times: list[int] = []
        for _, stamp, data in bag.messages(name, raw=True):
            raws.append(bytes(data))
            times.append(stamp)
        try:
            cols = decoder.decode(raws)
        except CorruptMessageError as err:
            raise BagCorruptError(
                blame_file(bag.path), f"{name}: message {err.index + 1}: {err.cause}"
            ) from err
        strings: dict[str, str] = {}
        if raws:
            first = store_.deserialize_cdr(raws[0], typename)
            strings = _strings(store_, typename, first)
        for added in ADDED_FIELDS.get(typename, ()):  # absent from an older bag: NaN
            cols.setdefault(added, np.full(len(raws), np.nan))
    if "header.stamp.sec" in cols:
        cols["stamp_ns"] = cols["header.stamp.sec"].astype(np.int64) * NS_PER_S + cols[
            "header.stamp.nanosec"
        ].astype(np.int64)
    return cols, np.array(times, dtype=np.int64), strings


def _strings(store: Typestore, typename: str, msg: Any, prefix: str = "") -> dict[str, str]:

    out: dict[str, str] = {}
    fields: Any = store.fielddefs[typename][1]  # rosbags' field-type union, by kind below
    for name, (kind, args) in fields:
        if kind == Nodetype.NAME:
            out.update(_strings(store, args, getattr(msg, name), f"{prefix}{name}."))
        elif kind == Nodetype.BASE and args[0] == "string":
            out[f"{prefix}{name}"] = str(getattr(msg, name))
    return out
