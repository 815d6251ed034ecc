"""Vectorized decoding of many CDR messages of one type into numpy columns.

Offline replay needs every field of millions of ``RigState`` messages as arrays; deserializing
each message into a Python object (rosbags ``deserialize_cdr``, ~5 us each) dominates such a
run. :class:`ColumnDecoder` instead walks the CDR layout of the type (derived from the
typestore, so fields added to a ``.msg`` file are picked up) for all messages of a batch at
once with numpy: per-message positions advance through variable-length strings and sequences,
alignment is applied relative to the payload start, every read is bounds-checked.

Supported: primitive fields, strings (skipped), nested messages, fixed arrays and sequences of
primitives. Other layouts (sequences of strings or messages) raise ``ValueError`` at
construction; callers fall back to per-message deserialization (:func:`columns_slow`).

Column names are dotted field paths (``header.stamp.sec``, ``actuating_pressure``). Fixed arrays
and sequences give 2-D arrays ``(n, width)``; sequences are padded with NaN (floats) or 0
(integers) beyond their length, which is given in ``<name>.len``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

from clutch_ros.bag.errors import CorruptMessageError  # re-exported: its old home

__all__ = ["ColumnDecoder", "CorruptMessageError", "columns_slow"]

_PRIM = {
    "bool": "u1", "byte": "u1", "char": "u1", "octet": "u1", "int8": "i1", "uint8": "u1",
    "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8",
    "uint64": "<u8", "float32": "<f4", "float64": "<f8",
}  # fmt: skip


def _steps(store: Typestore, typename: str, prefix: str = "") -> list[tuple]:
    """Flatten the CDR layout of ``typename`` into decoding steps."""
    out: list[tuple] = []
    fields: Any = store.fielddefs[typename][1]  # rosbags' field-type union, by kind below
    for name, (kind, args) in fields:
        path = f"{prefix}{name}"
        if kind == Nodetype.NAME:
            out.extend(_steps(store, args, f"{path}."))
        elif kind == Nodetype.BASE:
            if args[0] == "string":
                out.append(("string", path))
            elif args[0] in _PRIM:
                out.append(("prim", path, args[0]))
            else:
                raise ValueError(f"{path}: unsupported type {args[0]}")
        else:
            sub, size = args
            if sub[0] != Nodetype.BASE or sub[1][0] not in _PRIM:
                raise ValueError(f"{path}: arrays of {sub} are not supported")
            out.append(("array" if kind == Nodetype.ARRAY else "seq", path, sub[1][0], size))
    return out


def _out_dtype(prim: str) -> np.dtype:
    return np.dtype(bool) if prim == "bool" else np.dtype(_PRIM[prim]).newbyteorder("=")


class ColumnDecoder:
    """Decode batches of little-endian CDR messages of one type into numpy columns.

    Args:
        store: the typestore that defines ``typename``.
        typename: the ROS 2 type, e.g. ``clutch_msgs/msg/RigState``.
        fields: dotted field paths to return (default: every field). The others are still
            walked (and bounds-checked) but not copied out: a replay needs 6 of RigState's
            ~20 columns, and the 2-D ones are the largest.

    Raises:
        ValueError: the type has fields the vectorized path does not support, or ``fields``
            names a field it does not have.

    """

    def __init__(self, store: Typestore, typename: str, fields=None):
        self.typename = typename
        self.steps = _steps(store, typename)
        if fields is not None:
            known = {step[1] for step in self.steps if step[0] != "string"}
            unknown = sorted(set(fields) - known)
            if unknown:
                raise ValueError(f"{typename} has no field {', '.join(unknown)}")
            self.steps = [step if step[0] == "string" or step[1] in fields
                          else ("skip_" + step[0], *step[1:]) for step in self.steps]
        #: the fixed layout learnt from a batch whose messages all had one layout
        self._plan: _Plan | None = None

    def decode(self, raws: Sequence[bytes | memoryview]) -> dict[str, np.ndarray]:
        """Decode ``raws`` (CDR with 4-byte encapsulation header) into columns.

        Raises:
            CorruptMessageError: a message is not little-endian CDR or is shorter than its
                layout.

        """
        n = len(raws)
        if n == 0:
            return self._empty()
        lengths = np.fromiter(map(len, raws), dtype=np.int64, count=n)
        # 8 spare bytes: masked-out gathers near the end never index past the buffer
        buf = np.frombuffer(b"".join(raws) + bytes(8), dtype=np.uint8)
        starts = np.zeros(n, dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        return self.decode_buffer(buf, starts, lengths)

    def decode_buffer(
        self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Decode the messages ``buf[starts[i] : starts[i] + lengths[i]]`` into columns.

        Args:
            buf: uint8 buffer holding the messages, with >= 8 spare bytes after the last.
            starts: start of each message (its CDR header) in ``buf`` [bytes].
            lengths: length of each message including the CDR header [bytes].

        Raises:
            CorruptMessageError: see :meth:`decode`.

        """
        if len(starts) == 0:
            return self._empty()
        if (lengths < 4).any():
            raise CorruptMessageError(int(np.argmax(lengths < 4)), "shorter than the CDR header")
        bad = (buf[starts] != 0) | (buf[starts + 1] != 1)
        if bad.any():
            raise CorruptMessageError(int(np.argmax(bad)), "not little-endian CDR (encapsulation)")
        fast = self._plan.decode(buf, starts, lengths) if self._plan is not None else None
        if fast is not None:
            return fast
        walk = _Walk(buf, starts, lengths)
        cols = walk.run(self.steps)
        if walk.mat is not None and not walk.varying:
            self._plan = _Plan(int(lengths[0]), walk, self.steps)
        return cols

    def offsets(self, raw: bytes | memoryview) -> dict[str, int]:
        """Byte offset (from the start of ``raw``, header included) of each field's data.

        For a sequence, the offset of its first element. Used to patch a serialized template
        message in place (e.g. to generate large benchmark bags quickly).
        """
        walk = _Walk(
            np.frombuffer(bytes(raw) + bytes(8), dtype=np.uint8),
            np.zeros(1, dtype=np.int64),
            np.array([len(raw)], dtype=np.int64),
        )
        walk.run(self.steps)
        return {name: 4 + int(rel[0]) for name, rel in walk.offsets.items()}

    def _empty(self) -> dict[str, np.ndarray]:
        cols: dict[str, np.ndarray] = {}
        for step in self.steps:
            if step[0] == "prim":
                cols[step[1]] = np.zeros(0, dtype=_out_dtype(step[2]))
            elif step[0] in {"array", "seq"}:
                width = step[3] if step[0] == "array" else 0
                cols[step[1]] = np.zeros((0, width), dtype=_out_dtype(step[2]))
                if step[0] == "seq":
                    cols[f"{step[1]}.len"] = np.zeros(0, dtype=np.int64)
        return cols


class _Plan:
    """A fixed message layout: one length, every string and sequence of one length.

    Learnt from a walk over a batch in which every message had that layout; a later batch of
    equally spaced messages of the same length whose string lengths and sequence counts
    (read at their fixed offsets) all equal the learnt ones has the same layout, so each
    field is copied out of a strided view of the batch at its fixed offset, without the walk
    (the bounds were checked by the walk, on the same length). Same columns as the walk.
    """

    def __init__(self, length: int, walk: _Walk, steps: list[tuple]):
        self.length = length
        self.counts = walk.counts  # (payload offset of a length field, its value)
        # (name, payload offset, primitive, width or None for a scalar)
        self.fields: list[tuple[str, int, str, int | None]] = []
        for step in steps:
            if step[0] == "prim":
                self.fields.append((step[1], int(walk.offsets[step[1]][0]), step[2], None))
            elif step[0] in {"array", "seq"}:
                width = step[3] if step[0] == "array" else walk.seq_counts[step[1]]
                self.fields.append((step[1], int(walk.offsets[step[1]][0]), step[2], width))
                if step[0] == "seq":
                    self.fields.append((f"{step[1]}.len", -1, "", width))

    def decode(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray
               ) -> dict[str, np.ndarray] | None:
        """Return the batch's columns, or None when it does not have this layout."""
        n, length = len(starts), self.length
        stride = int(starts[1] - starts[0]) if n > 1 else length
        if stride < length or not (lengths == length).all() or \
                (n > 2 and not (np.diff(starts) == stride).all()):
            return None
        mat = np.lib.stride_tricks.as_strided(buf[int(starts[0]):], shape=(n, length),
                                              strides=(stride, 1), writeable=False)
        for off, value in self.counts:
            if not (_strided(mat, 4 + off, "uint32", 1)[:, 0] == value).all():
                return None
        cols: dict[str, np.ndarray] = {}
        for name, off, prim, width in self.fields:
            if off < 0:
                cols[name] = np.full(n, width, dtype=np.int64)
                continue
            values = _strided(mat, 4 + off, prim, width or 1)
            if prim == "bool":
                out = values != 0
            else:
                out = np.empty(values.shape, dtype=_out_dtype(prim))
                out[:] = values
            cols[name] = out[:, 0] if width is None else out
        return cols


def _strided(mat: np.ndarray, off: int, prim: str, width: int) -> np.ndarray:
    """``width`` values of type ``prim`` at byte ``off`` of each row of ``mat``: (n, width) view."""
    dtype = np.dtype(_PRIM[prim])
    raw = mat[:, off : off + width * dtype.itemsize]
    return raw.view(dtype) if dtype.itemsize > 1 else raw


class _Walk:
    """State of one vectorized walk: per-message payload positions ``rel``."""

    def __init__(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray):
        self.buf = buf
        self.base = starts + 4  # payload start of each message in buf
        self.ends = lengths - 4  # payload length of each message
        self.rel = np.zeros(len(starts), dtype=np.int64)
        self.offsets: dict[str, np.ndarray] = {}  # payload offset of each field's data
        self.const = True  # rel equal for all messages
        self.varying = False  # a string or sequence length differs between messages
        self.counts: list[tuple[int, int]] = []  # (payload offset, value) of each length field
        self.seq_counts: dict[str, int] = {}
        # equal lengths at equal spacing: a strided (n, length) view gives column slices
        self.mat: np.ndarray | None = None
        n, length = len(starts), int(lengths[0])
        stride = int(starts[1] - starts[0]) if n > 1 else length
        self.uniform = bool((lengths == length).all())  # every message of one length
        if self.uniform and (n == 1 or (np.diff(starts) == stride).all()):
            self.mat = np.lib.stride_tricks.as_strided(
                buf[int(starts[0]) :], shape=(n, length), strides=(stride, 1), writeable=False
            )

    def _check(self, need: np.ndarray | int, what: str) -> None:
        if self.const and self.uniform and isinstance(need, int):  # one comparison for all
            if int(self.rel[0]) + need > int(self.ends[0]):
                raise CorruptMessageError(0, f"truncated at {what}")
            return
        over = self.rel + need > self.ends
        if over.any():
            raise CorruptMessageError(int(np.argmax(over)), f"truncated at {what}")

    def _gather(self, rel: np.ndarray, prim: str, const: bool) -> np.ndarray:
        dtype = np.dtype(_PRIM[prim])
        size = dtype.itemsize
        if const and self.mat is not None:
            off = 4 + int(rel[0])
            # the field's bytes of every message viewed as one strided (n, 1) column: one
            # copy into an aligned array, no intermediate byte array
            values = self.mat[:, off : off + size].view(dtype).reshape(-1)
        else:
            raw = self.buf[(self.base + rel)[:, None] + np.arange(size)]
            values = raw.view(dtype).reshape(-1)
        if prim == "bool":
            return values.astype(bool)
        out = np.empty(len(values), dtype=_out_dtype(prim))
        out[:] = values
        return out

    def _align(self, size: int, where: np.ndarray | None = None) -> None:
        """Align ``rel`` to ``size`` (only where ``where`` is true, if given)."""
        if size <= 1:
            return
        if where is None and self.const:  # align one offset; shift all only if it moves
            rel = int(self.rel[0])
            shift = ((rel + size - 1) & -size) - rel
            if shift:
                self.rel = self.rel + shift
            return
        aligned = (self.rel + size - 1) & -size
        if where is None:
            self.rel = aligned  # keeps ``const``
        else:
            self.rel = np.where(where, aligned, self.rel)
            self._refresh_const()

    def _note(self, count: np.ndarray, name: str) -> None:
        """Keep a length field's offset and value while it is one for every message."""
        if self.varying or not self.const or not (count == count[0]).all():
            self.varying = True
            return
        self.counts.append((int(self.rel[0]), int(count[0])))
        self.seq_counts[name] = int(count[0])

    def _refresh_const(self) -> None:
        self.const = bool(self.rel.min() == self.rel.max())

    def run(self, steps: list[tuple]) -> dict[str, np.ndarray]:
        cols: dict[str, np.ndarray] = {}
        for step in steps:
            kind, name = step[0], step[1]
            if kind == "skip_prim":  # walked, not copied out
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(size)
                self._check(size, name)
                self.offsets[name] = self.rel
                self.rel = self.rel + size
            elif kind == "skip_array":
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(size)
                self._check(size * step[3], name)
                self.offsets[name] = self.rel
                self.rel = self.rel + size * step[3]
            elif kind == "skip_seq":
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(4)
                self._check(4, name)
                count = self._gather(self.rel, "uint32", self.const).astype(np.int64)
                self._note(count, name)
                self.rel = self.rel + 4
                self._align(size, where=count > 0)
                self._check(count * size, name)
                self.offsets[name] = self.rel
                self.rel = self.rel + count * size
                self._refresh_const()
            elif kind == "prim":
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(size)
                self._check(size, name)
                self.offsets[name] = self.rel
                cols[name] = self._gather(self.rel, step[2], self.const)
                self.rel = self.rel + size
            elif kind == "string":
                self._align(4)
                self._check(4, name)
                count = self._gather(self.rel, "uint32", self.const).astype(np.int64)
                self._note(count, name)
                self.rel = self.rel + 4
                self._check(count, name)
                self.rel = self.rel + count
                self._refresh_const()
            elif kind == "array":
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(size)
                self._check(size * step[3], name)
                self.offsets[name] = self.rel
                cols[name] = self._elements(step[2], np.full(len(self.rel), step[3]), step[3])
                self.rel = self.rel + size * step[3]
            else:
                size = np.dtype(_PRIM[step[2]]).itemsize
                self._align(4)
                self._check(4, name)
                count = self._gather(self.rel, "uint32", self.const).astype(np.int64)
                self._note(count, name)
                self.rel = self.rel + 4
                self._align(size, where=count > 0)
                self._check(count * size, name)
                self.offsets[name] = self.rel
                width = int(count.max()) if len(count) else 0
                cols[name] = self._elements(step[2], count, width)
                cols[f"{name}.len"] = count
                self.rel = self.rel + count * size
                self._refresh_const()
        return cols

    def _elements(self, prim: str, count: np.ndarray, width: int) -> np.ndarray:
        """Gather up to ``width`` elements per message into a padded ``(n, width)`` array."""
        size = np.dtype(_PRIM[prim]).itemsize
        dtype = _out_dtype(prim)
        out = np.zeros((len(count), width), dtype=dtype)
        if dtype.kind == "f":
            out[:] = np.nan
        full = bool((count == width).all())
        for k in range(width):
            if full:
                out[:, k] = self._gather(self.rel + k * size, prim, self.const)
            else:
                has = count > k
                rel = np.where(has, self.rel + k * size, 0)
                values = self._gather(rel, prim, False)
                out[has, k] = values[has]
        return out


def columns_slow(store: Typestore, typename: str, raws: Sequence[bytes]) -> dict[str, Any]:
    """Per-message fallback of :meth:`ColumnDecoder.decode` for any primitive-field layout.

    Deserializes every message with rosbags and collects the primitive fields (dotted paths);
    strings and sequences of non-primitives are skipped.
    """
    msgs = [store.deserialize_cdr(raw, typename) for raw in raws]
    cols: dict[str, Any] = {}

    def walk(typ: str, getter: Any, prefix: str) -> None:
        fields: Any = store.fielddefs[typ][1]  # rosbags' field-type union, by kind below
        for name, (kind, args) in fields:
            path = f"{prefix}{name}"

            def get(m: Any, _name: str = name) -> Any:
                return getattr(getter(m), _name)

            if kind == Nodetype.NAME:
                walk(args, get, f"{path}.")
            elif kind == Nodetype.BASE and args[0] in _PRIM:
                cols[path] = np.array([get(m) for m in msgs], dtype=_out_dtype(args[0]))
            elif kind in {Nodetype.ARRAY, Nodetype.SEQUENCE} and args[0][0] == Nodetype.BASE:
                if args[0][1][0] not in _PRIM:
                    continue
                seqs = [np.asarray(get(m)) for m in msgs]
                count = np.array([len(s) for s in seqs], dtype=np.int64)
                width = int(count.max()) if len(count) else 0
                dtype = _out_dtype(args[0][1][0])
                arr = np.full((len(seqs), width), np.nan if dtype.kind == "f" else 0, dtype)
                for i, seq in enumerate(seqs):
                    arr[i, : len(seq)] = seq
                cols[path] = arr
                if kind == Nodetype.SEQUENCE:
                    cols[f"{path}.len"] = count

    walk(typename, lambda m: m, "")
    return cols
