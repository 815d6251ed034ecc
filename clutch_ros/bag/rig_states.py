"""RigState bags as numpy columns: :func:`read_rig_states` and its two read paths.

Two ways to get the raw CDR bytes of one topic, both decoded in bulk with numpy by
:class:`~clutch_ros.bag.columns.ColumnDecoder`:

- :func:`read_fast`: uncompressed MCAP files are scanned directly
  (:func:`~clutch_ros.bag.fastmcap.scan_chunks`), when metadata.yaml agrees with the storage;
  messages are sorted by bag timestamp (stable), as rosbags yields them.
- :func:`read_via_rosbags`: any bag, through :meth:`BagReader.messages` (``raw=True``).

Both check the number of messages against the count the bag declares.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from clutch_ros.bag.columns import ColumnDecoder, CorruptMessageError, _steps, columns_slow
from clutch_ros.bag.diagnose import blame_file, load_metadata, storage_files, storage_issues
from clutch_ros.bag.errors import BagCorruptError, BagCountMismatchError, BagError
from clutch_ros.bag.fastmcap import scan_chunks
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.typestore import RIG_STATE_TYPE, Typestore, topic_name
from clutch_ros.interfaces import NS_PER_S, stamp_to_s

__all__ = ["REPLAY_FIELDS", "ColumnSink", "RigStateArrays", "mcap_files", "model_inputs",
           "read_fast", "read_rig_states", "read_via_rosbags"]

#: The RigState fields the estimator needs (``clutch replay`` without a report).
REPLAY_FIELDS = ("header.stamp.sec", "header.stamp.nanosec", "actuating_pressure",
                 "lamella_temperature", "slip_speed", "measured_torque", "has_measured_torque")


class RigStateArrays:
    """Every ``RigState`` field of a bag topic as numpy arrays (one element per message).

    Attribute access returns columns by field name: ``actuating_pressure`` [Pa],
    ``lamella_temperature``, ``oil_temperature`` [degC], ``input_speed``, ``output_speed``,
    ``slip_speed`` [rad/s], ``measured_torque`` [N m], ``has_measured_torque`` (bool),
    ``torque_request`` [N m], ``pump_current`` [A], ``stale_mask``, ``ff_voltages`` [V] and
    ``wheel_speeds`` [rad/s] as ``(n, width)`` arrays padded with NaN (lengths in
    ``columns["ff_voltages.len"]``). Fields added to RigState.msg appear automatically.

    Attributes:
        path: the bag.
        topic: the topic read.
        stamp_ns: header stamps [ns since epoch] (int64).
        stamp: header stamps [s since epoch] (float64).
        time: header stamps relative to the first message [s].
        bag_time_ns: bag (receive) timestamps [ns since epoch] (int64).
        columns: all columns by dotted field path (``header.stamp.sec`` ...).

    """

    def __init__(self, path: Path, topic: str, columns: dict[str, np.ndarray], bag_ns: np.ndarray):
        self.path = path
        self.topic = topic
        self.columns = columns
        sec = columns["header.stamp.sec"].astype(np.int64)
        self.stamp_ns = sec * NS_PER_S + columns["header.stamp.nanosec"].astype(np.int64)
        self.stamp = self.stamp_ns / 1e9
        self.time = (self.stamp_ns - (self.stamp_ns[0] if len(self.stamp_ns) else 0)) / 1e9
        self.bag_time_ns = bag_ns

    def __len__(self) -> int:
        return len(self.stamp_ns)

    def __getattr__(self, name: str) -> np.ndarray:
        columns = self.__dict__.get("columns", {})
        if name in columns:
            return columns[name]
        raise AttributeError(f"RigStateArrays has no field {name!r}")


def model_inputs(columns: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Return the estimator's inputs from RigState columns: ``(t, p, temp, omega, measured)``.

    ``t``: header stamps [s] as the node computes them
    (:func:`clutch_ros.interfaces.stamp_to_s`: ``sec + nanosec * 1e-9`` in float64, so both
    see bit-identical time steps); actuating pressure [Pa]; lamella temperature [°C]; slip
    speed [rad/s]; measured torque [N m], NaN where ``has_measured_torque`` is false.
    Element by element, so a block's inputs are the whole stream's rows.
    """
    t = stamp_to_s(columns["header.stamp.sec"].astype(np.float64),
                   columns["header.stamp.nanosec"].astype(np.float64))
    measured = np.where(columns["has_measured_torque"].astype(bool),
                        columns["measured_torque"], np.nan)
    return (t, columns["actuating_pressure"], columns["lamella_temperature"],
            columns["slip_speed"], measured)


class ColumnSink:
    """Collect decoded batches into preallocated column arrays (no final concatenation).

    Args:
        capacity: expected number of rows (the count the bag declares); grows if exceeded.

    2-D columns (sequences) widen when a later batch is wider; missing cells are NaN (float)
    or 0 (integer).
    """

    def __init__(self, capacity: int):
        self.capacity = max(int(capacity), 1)
        self.rows = 0
        self.cols: dict[str, np.ndarray] | None = None

    @staticmethod
    def _alloc(like: np.ndarray, rows: int, width: int | None = None) -> np.ndarray:
        # not filled: every cell up to ``rows`` is written by add() (first touch of a large
        # column costs as much as the copy itself)
        shape = (rows,) if like.ndim == 1 else (rows, like.shape[1] if width is None else width)
        return np.empty(shape, dtype=like.dtype)

    @staticmethod
    def _pad(like: np.ndarray) -> float:
        return np.nan if like.dtype.kind == "f" else 0

    def add(self, part: dict[str, np.ndarray]) -> None:
        """Append one batch of columns (all of the same length)."""
        n = len(next(iter(part.values()))) if part else 0
        if self.cols is None:
            self.cols = {k: self._alloc(v, max(self.capacity, n)) for k, v in part.items()}
        cols = self.cols
        end = self.rows + n
        for key, arr in part.items():
            out = cols[key]
            if end > len(out) or (arr.ndim == 2 and arr.shape[1] > out.shape[1]):
                width = max(arr.shape[1], out.shape[1]) if arr.ndim == 2 else None
                grown = self._alloc(arr, max(end, 2 * len(out)), width)
                if out.ndim == 2:
                    grown[: self.rows, : out.shape[1]] = out[: self.rows]
                    grown[: self.rows, out.shape[1] :] = self._pad(out)
                else:
                    grown[: self.rows] = out[: self.rows]
                cols[key] = out = grown
            if arr.ndim == 2:
                out[self.rows : end, : arr.shape[1]] = arr
                out[self.rows : end, arr.shape[1] :] = self._pad(out)
            else:
                out[self.rows : end] = arr
        self.rows = end

    def result(self, empty: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Return the columns (``empty`` if nothing was added)."""
        if self.cols is None:
            return empty
        return {k: v[: self.rows] for k, v in self.cols.items()}


def mcap_files(bag: BagReader) -> list[Path] | None:
    """Return the MCAP files of a bag the fast scan can read (uncompressed bag), else None."""
    if not bag.path.is_dir():
        return [bag.path] if bag.path.suffix == ".mcap" else None
    meta = load_metadata(bag.path)
    if meta is None or str(meta.get("storage_identifier")) != "mcap":
        return None
    if str(meta.get("compression_mode") or "").lower() not in {"", "none"}:
        return None
    return storage_files(bag.path, meta)


def read_fast(
    bag: BagReader, topic: str, decoder: ColumnDecoder, files: list[Path], on_block=None
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Scan the MCAP files directly; same count check and order as the rosbags path.

    ``on_block``: see :func:`read_rig_states`.

    Only valid when metadata.yaml agrees with the storage (``storage_issues`` empty): the scan
    selects messages by channel topic, while rosbags also requires the QoS to match.
    """
    declared = sum(c.msgcount for c in bag.reader.connections if c.topic == topic)
    sink = ColumnSink(declared)
    times: list[np.ndarray] = []
    done = 0
    for file in files:
        try:
            for block in scan_chunks(file, {topic}):
                part = decoder.decode_buffer(block.buf, block.starts, block.lengths)
                sink.add(part)
                times.append(block.times)
                done += len(block.times)
                if on_block is not None:
                    on_block(part, block.times, declared)
        except CorruptMessageError as err:
            raise BagCorruptError(
                file, f"{topic}: message {done + err.index + 1}: {err.cause}"
            ) from err
        except Exception as err:  # noqa: BLE001 - FastMcapError, struct.error, zstd errors
            raise BagCorruptError(file, f"cannot read messages: {err}") from err
    if done != declared:
        raise BagCountMismatchError(
            bag.path,
            f"{topic}: read {done} messages but the bag declares {declared}",
            topic=topic, expected=declared, actual=done,
        )  # fmt: skip
    stamps = np.concatenate(times) if times else np.zeros(0, dtype=np.int64)
    columns = sink.result(decoder.decode([]))
    if len(stamps) > 1 and (np.diff(stamps) < 0).any():  # rosbags order: by log time, stable
        order = np.argsort(stamps, kind="stable")
        stamps = stamps[order]
        columns = {k: v[order] for k, v in columns.items()}
    return columns, stamps


def read_via_rosbags(
    bag: BagReader, topic: str, decoder: ColumnDecoder | None, batch: int, on_block=None
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Read raw messages through rosbags (any storage) and decode them in batches.

    ``on_block``: see :func:`read_rig_states`.
    """
    declared = sum(c.msgcount for c in bag.reader.connections if c.topic == topic)
    sink = ColumnSink(declared)
    empty: list[dict[str, np.ndarray]] = []
    stamps: list[np.ndarray] = []
    raws: list[bytes] = []
    times: list[int] = []
    done = 0

    def flush() -> None:
        nonlocal done
        try:
            if decoder is None:
                part = columns_slow(bag.store, RIG_STATE_TYPE, raws)
            else:
                part = decoder.decode(raws)
        except CorruptMessageError as err:
            raise BagCorruptError(
                blame_file(bag.path), f"{topic}: message {done + err.index + 1}: {err.cause}"
            ) from err
        except Exception as err:  # noqa: BLE001 - slow path: rosbags SerdeError
            raise BagCorruptError(blame_file(bag.path), f"{topic}: cannot decode: {err}") from err
        block_times = np.array(times, dtype=np.int64)
        if raws:
            sink.add(part)
            if on_block is not None:
                on_block(part, block_times, declared)
        else:
            empty.append(part)
        stamps.append(block_times)
        done += len(raws)
        raws.clear()
        times.clear()

    for _, timestamp, data in bag.messages(topic, raw=True):
        raws.append(data)
        times.append(timestamp)
        if len(raws) >= batch:
            flush()
    if raws or not done:
        flush()
    return sink.result(empty[0] if empty else {}), np.concatenate(stamps)


def read_rig_states(
    path: str | Path,
    topic: str | None = None,
    *,
    store: Typestore | None = None,
    batch: int = 65536,
    fast: bool = True,
    fields=None,
    on_block: Callable[[dict[str, np.ndarray], np.ndarray, int], None] | None = None,
) -> RigStateArrays:
    """Read every ``RigState`` of a bag topic into numpy arrays, fast (no message objects).

    Uncompressed MCAP bags whose metadata.yaml agrees with the storage are scanned directly
    (:mod:`~clutch_ros.bag.fastmcap`) after rosbags opened them; other bags are read through
    rosbags (:meth:`BagReader.messages`). Both decode the CDR bytes with numpy, order messages
    by bag timestamp as rosbags does, and check the count the bag declares.

    Args:
        path: bag directory or storage file.
        topic: the topic; default: the bag's only topic of type RigState.
        store: typestore.
        batch: messages decoded per numpy batch (rosbags path).
        fast: allow the direct MCAP scan.
        fields: dotted field paths to decode (default: every field); the header stamp is
            always read. A replay reads only what the model needs (:data:`REPLAY_FIELDS`).
        on_block: called after each decoded block, in file order, with ``(columns, log
            times [ns], declared count)``, so a consumer can start on the data while the
            read goes on (``clutch replay`` estimates meanwhile). The final arrays are these
            blocks in this order unless their log times are out of order (then they are
            sorted; a consumer checks the times it was given). The callback must not keep
            the block's arrays beyond its own use of them (they may be views of the file).

    Raises:
        BagError: no (or more than one) RigState topic; plus everything :class:`BagReader`
            raises (including the count check).

    """
    with BagReader(path, store=store) as bag:
        if topic is None:
            found = [t for t, info in bag.topics.items() if info.typename == RIG_STATE_TYPE]
            if len(found) != 1:
                raise BagError(
                    bag.path,
                    f"expected one {RIG_STATE_TYPE} topic, found {found or 'none'}; choose the "
                    "topic with --topic TOPIC",
                )
            topic = found[0]
        topic = topic_name(topic)
        for conn in bag._select(topic):
            if conn.msgtype != RIG_STATE_TYPE:
                raise BagError(bag.path, f"topic {topic} has type {conn.msgtype}, not RigState")
            bag._check_type(conn)
        if fields is not None:
            fields = set(fields) | {"header.stamp.sec", "header.stamp.nanosec"}
            unknown = fields - set(_field_paths(bag.store))
            if unknown:
                raise BagError(bag.path, f"RigState has no field {', '.join(sorted(unknown))}")
        try:
            decoder: ColumnDecoder | None = ColumnDecoder(bag.store, RIG_STATE_TYPE, fields)
        except ValueError:
            decoder = None
        files = mcap_files(bag) if fast and decoder is not None else None
        if files is not None and storage_issues(bag.path, bag.reader.connections):
            files = None  # let rosbags read it, so the outcome is the checked reader's
        if files is not None and decoder is not None:
            columns, stamps = read_fast(bag, topic, decoder, files, on_block)
        else:
            columns, stamps = read_via_rosbags(bag, topic, decoder, batch, on_block)
            if fields is not None:  # the per-message fallback decodes every field
                columns = {k: v for k, v in columns.items()
                           if k in fields or k.removesuffix(".len") in fields}
        return RigStateArrays(bag.path, topic, columns, stamps)


def _field_paths(store: Typestore) -> list[str]:
    """Dotted paths of RigState's primitive, array and sequence fields."""
    return [step[1] for step in _steps(store, RIG_STATE_TYPE) if step[0] != "string"]
