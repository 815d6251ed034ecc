"""Writing rosbag2 bags (MCAP by default, sqlite3 selectable) with rosbags, no rclpy.

Bags written here are meant to be indistinguishable, for ``ros2 bag info`` / ``ros2 bag play``
on Jazzy and Kilted, from bags recorded by ``ros2 bag record``:

- rosbag2 metadata version 9 (Jazzy/Kilted): ``metadata.yaml`` with per-topic and per-file
  message counts, start time and duration; ``offered_qos_profiles`` as a YAML list with policy
  names (``reliable``, ``best_effort``, ``keep_last``...) and infinite durations as
  ``{sec: 9223372036, nsec: 854775807}`` (``RMW_DURATION_INFINITE``), which is what the
  recorder stores for publishers that leave them at their defaults (rosbags' version 9
  writer, ``dump_qos_v9``, the format rosbag2 Jazzy and Kilted write). The offered QoS of a
  clutch topic is what its publisher offers, from the one table
  :data:`clutch_ros.interfaces.TOPICS` (``rig_state``: reliable, keep last 50, as the
  can_bridge offers it); ``ros2 bag play`` offers the recorded reliability/durability again.
- MCAP: ``ros2`` profile, ``ros2msg`` schemas, per-channel ``offered_qos_profiles`` metadata,
  chunk and message indexes, a Statistics record (total and per-channel message counts, time
  range) and the ``rosbag2`` metadata record, all written by rosbags.
- MCAP chunks carry the CRC-32 of their records; with ``chunk_interval`` (the recorder) each
  is closed on time and flushed, and with ``sync`` fsync'd, so a crash loses at most the
  open chunk (:mod:`clutch_ros.bag.chunked`; ``clutch replay --recover`` reads the rest).
- sqlite3: schema version 4 with ``message_definitions`` and a ``metadata`` table.
- Optional zstd chunk compression for MCAP (``compression="zstd"``, what ``ros2 bag record
  --storage-preset-profile zstd_fast`` writes): metadata.yaml keeps ``compression_mode: ''``
  (the compression is inside the storage file), every MCAP reader decompresses it.

Topic names are stored absolute (``/rig_state``), as ``ros2 bag record`` stores the fully
qualified names; relative names given here are qualified with ``namespace`` (default ``/``).

Counts in = counts out: :attr:`BagWriter.written` counts every message accepted per topic;
on close the bag is reopened, ``metadata.yaml`` must agree with the storage file
(``BagMetadataMismatchError`` otherwise) and its counts must equal ``written``
(``BagCountMismatchError`` otherwise). Messages lost before the writer can be reported with
:meth:`BagWriter.mark_dropped`; they are recorded in the bag's ``custom_data``.
"""

from __future__ import annotations

import shutil
import struct
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, WriterError

from clutch_ros import interfaces
from clutch_ros.bag.chunked import ChunkedMcapWriter, ChunkedWriter, ChunkPolicy
from clutch_ros.bag.errors import BagError, BagExistsError, MessageFieldError, UnknownTypeError
from clutch_ros.bag.reader import check_bag
from clutch_ros.bag.typestore import (
    RIG_STATE_TYPE,
    Typestore,
    clutch_typestore,
    rig_state_msg,
    topic_name,
)
from clutch_ros.errors import ConfigError
from clutch_ros.interfaces import QosSpec

__all__ = [
    "INFINITE",
    "RELIABLE_QOS",
    "SENSOR_DATA_QOS",
    "STORAGES",
    "TOPICS",
    "COMPRESSIONS",
    "BagWriter",
    "make_qos",
    "qos_of",
    "storage_plugin",
    "write_rig_states",
]

#: ``RMW_DURATION_INFINITE`` as rosbag2 (Jazzy and later) stores it [s, ns].
INFINITE = QosTime(9223372036, 854775807)


def _duration(ns: int | None) -> QosTime:
    """Return a duration [ns] as rosbag2 stores it; None (infinite) as :data:`INFINITE`."""
    if ns is None:
        return INFINITE
    sec, nsec = interfaces.ns_to_stamp(ns)
    return QosTime(sec, nsec)


def qos_of(spec: QosSpec) -> Qos:
    """Return the rosbags offered-QoS record of a :class:`~clutch_ros.interfaces.QosSpec`.

    Policy names map to rosbags' enums by name (``best_effort`` -> ``BEST_EFFORT``), so the
    ``metadata.yaml`` text is the spec's own spelling.
    """
    return Qos(
        QosHistory[spec.history.upper()],
        spec.depth,
        QosReliability[spec.reliability.upper()],
        QosDurability[spec.durability.upper()],
        _duration(spec.deadline_ns),
        _duration(spec.lifespan_ns),
        QosLiveliness[spec.liveliness.upper()],
        _duration(spec.liveliness_lease_ns),
        False,
    )


def make_qos(reliable: bool, depth: int, transient_local: bool = False) -> Qos:
    """Return an offered QoS profile (keep-last ``depth``, automatic liveliness, no deadline)."""
    return qos_of(QosSpec(
        interfaces.RELIABLE if reliable else interfaces.BEST_EFFORT,
        interfaces.TRANSIENT_LOCAL if transient_local else interfaces.VOLATILE, depth))


#: ``rclpy.qos.qos_profile_sensor_data``: best effort, keep last 5, volatile.
SENSOR_DATA_QOS = qos_of(interfaces.SENSOR_DATA)
#: rclpy's default publisher profile: reliable, keep last 10, volatile (a topic not in the
#: table).
RELIABLE_QOS = make_qos(reliable=True, depth=10)

#: Type and offered QoS (what its publisher offers) of every clutch topic, by absolute
#: name, from :data:`clutch_ros.interfaces.TOPICS`.
TOPICS: dict[str, tuple[str, Qos]] = {
    t.absolute: (t.typename, qos_of(t.publisher)) for t in interfaces.TOPICS
}

#: Storage identifiers accepted by :class:`BagWriter`.
STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
#: Compression choices of :class:`BagWriter` (``zstd``: MCAP chunk compression).
COMPRESSIONS = ("none", "zstd")


def storage_plugin(storage: str) -> StoragePlugin:
    """Map ``"mcap"`` / ``"sqlite3"`` (case-insensitive) to the rosbags storage plugin.

    Raises:
        ConfigError: unknown storage name.

    """
    try:
        return STORAGES[str(storage).lower()]
    except KeyError:
        raise ConfigError(f"unknown bag storage {storage!r}; use one of: mcap, sqlite3") from None



class BagWriter:
    """Context manager writing one rosbag2 bag.

    Args:
        path: bag directory to create; must not exist (bags are never overwritten).
        storage: ``"mcap"`` (default) or ``"sqlite3"``.
        store: typestore (default :func:`~clutch_ros.bag.typestore.clutch_typestore`).
        custom_data: string key/value pairs stored in ``metadata.yaml`` ``custom_data``.
        namespace: namespace that resolves relative topic names (default ``/``).
        delete_on_error: remove the bag directory if the ``with`` block raises (for imports;
            a recorder keeps partial data instead).
        verify: on close, reopen the bag and check the declared and stored counts.
        compression: ``"none"`` (default) or ``"zstd"``: zstd-compressed MCAP chunks (about
            half the size for rig data; MCAP only).
        chunk_interval: close each MCAP chunk once its first message is this old [s] (and
            flush it to the operating system), so a crash loses at most that much; None
            (default): chunks of 1 MiB of records (:mod:`clutch_ros.bag.chunked`).
        sync: fsync the MCAP file after each chunk (a power cut loses only the open chunk).

    Raises:
        BagExistsError: ``path`` exists.
        ConfigError: unknown storage or compression, or zstd with sqlite3.

    """

    def __init__(
        self,
        path: str | Path,
        *,
        storage: str = "mcap",
        store: Typestore | None = None,
        custom_data: Mapping[str, str] | None = None,
        namespace: str = "/",
        delete_on_error: bool = False,
        verify: bool = True,
        compression: str = "none",
        chunk_interval: float | None = None,
        sync: bool = False,
    ):
        self.path = Path(path)
        self.storage = str(storage).lower()
        self._plugin = storage_plugin(storage)
        self.compression = str(compression).lower()
        if self.compression not in COMPRESSIONS:
            raise ConfigError(
                f"unknown bag compression {compression!r}; use one of: {', '.join(COMPRESSIONS)}"
            )
        if self.compression != "none" and self._plugin != StoragePlugin.MCAP:
            raise ConfigError(f"{self.compression} compression needs the mcap storage")
        if chunk_interval is not None and not chunk_interval > 0:
            raise ConfigError(f"chunk_interval must be > 0 s, got {chunk_interval!r}")
        self.chunking = ChunkPolicy(chunk_interval, bool(sync))
        self.store = store or clutch_typestore()
        self.namespace = namespace
        self.delete_on_error = delete_on_error
        self.verify = verify
        self._custom = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._writer: ChunkedWriter | None = None
        self._conns: dict[str, Any] = {}
        self._types: dict[str, str] = {}
        #: messages accepted per topic (absolute name) [messages].
        self.written: dict[str, int] = {}
        #: messages the caller reports lost before reaching the writer, per topic [messages].
        self.dropped: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.closed = False
        if self.path.exists():
            raise BagExistsError(self.path, "output exists already; bags are never overwritten")

    # -- lifecycle ---------------------------------------------------------------------------
    def open(self) -> BagWriter:
        """Create the bag directory and storage file."""
        if self._writer is not None:
            return self
        if self.path.exists():
            raise BagExistsError(self.path, "output exists already; bags are never overwritten")
        writer = ChunkedWriter(self.path, version=ChunkedWriter.VERSION_LATEST,
                               storage_plugin=self._plugin, policy=self.chunking)
        if self.compression == "zstd":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in self._custom.items():
            writer.set_custom_data(key, value)
        try:
            writer.open()
        except WriterError as err:
            raise BagExistsError(self.path, str(err)) from err
        except OSError as err:
            raise BagError(self.path, f"cannot create bag: {err.strerror or err}") from err
        self._writer = writer
        return self

    def close_chunk_if_due(self, ahead: float = 0.0) -> bool:
        """Close the open MCAP chunk if ``chunk_interval`` is up within ``ahead`` [s].

        Call it from a timer every ``ahead`` seconds: chunks then close on time however
        quiet the topics are. Returns True when a chunk was closed (False for sqlite3).
        """
        storage = self._writer.storage if self._writer is not None else None
        try:
            return isinstance(storage, ChunkedMcapWriter) and storage.close_if_due(ahead)
        except OSError as err:
            raise BagError(self.path, f"cannot close the open chunk: {err}") from err

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def close(self) -> dict[str, int]:
        """Finish the bag (indexes, statistics, metadata.yaml) and verify the counts.

        Returns:
            messages written per topic [messages].

        Raises:
            BagCountMismatchError: the reopened bag declares or stores other counts.

        """
        if self._writer is None or self.closed:
            return dict(self.written)
        if self.dropped:
            lost = ",".join(f"{topic}={n}" for topic, n in sorted(self.dropped.items()))
            self._writer.set_custom_data("clutch_ros.dropped", lost)
        try:
            self._writer.close()
        except (OSError, WriterError, struct.error) as err:
            raise BagError(self.path, f"cannot finish bag: {err}") from err
        finally:
            self.closed = True
        if self.verify:

            check_bag(self.path, expected=self.written)
        return dict(self.written)

    def abort(self) -> None:
        """Stop writing after an error: keep the partial bag, or delete it (``delete_on_error``).

        A partial MCAP bag has no summary or ``metadata.yaml``; ``ros2 bag reindex`` can
        recover it. rosbags' sqlite3 writer rolls back everything not yet committed.
        """
        if self._writer is not None and not self.closed:
            try:
                self._writer.abort()
            except Exception:  # noqa: BLE001 - abort must not mask the original error
                pass
            self.closed = True
            if self.delete_on_error and self.path.is_dir():
                shutil.rmtree(self.path, ignore_errors=True)

    # -- topics and messages -----------------------------------------------------------------
    def add_topic(self, name: str, typename: str | None = None, *,
                  qos: Qos | Sequence[Qos] | None = None) -> str:
        """Declare a topic; returns its absolute name.

        Args:
            name: topic name (relative names are resolved in the namespace).
            typename: ROS 2 type; default: the clutch type of a known topic (:data:`TOPICS`).
            qos: offered QoS recorded for ``ros2 bag play``, one profile or one per publisher
                (as ``ros2 bag record`` stores them); default: what the topic's publisher
                offers (:data:`TOPICS`), reliable keep last 10 for any other topic.

        Raises:
            UnknownTypeError: type not in the typestore, or no type given for an unknown topic.
            BagError: the topic was declared already with another type.

        """
        topic = topic_name(name, self.namespace)
        default_type, default_qos = TOPICS.get("/" + topic.rsplit("/", 1)[-1], (None, RELIABLE_QOS))
        typename = typename or default_type
        if typename is None:
            raise UnknownTypeError(
                self.path, f"no message type given for topic {topic}", typename=""
            )
        if typename not in self.store.types:
            raise UnknownTypeError(
                self.path,
                f"type {typename} of topic {topic} is not in the typestore",
                typename=typename,
            )
        if topic in self._conns:
            if self._types[topic] != typename:
                raise BagError(self.path, f"topic {topic} already added as {self._types[topic]}")
            return topic
        self.open()
        assert self._writer is not None
        profiles = [default_qos] if not qos else [qos] if isinstance(qos, Qos) else list(qos)
        self._conns[topic] = self._writer.add_connection(
            topic, typename, typestore=self.store, offered_qos_profiles=profiles
        )
        self._types[topic] = typename
        self.written[topic] = 0
        return topic

    def set_custom_data(self, key: str, value: str) -> None:
        """Set a ``metadata.yaml`` ``custom_data`` entry (any time before :meth:`close`)."""
        if self.closed:
            raise BagError(self.path, "bag is closed")
        self._custom[str(key)] = str(value)
        if self._writer is not None:
            self._writer.set_custom_data(str(key), str(value))

    def mark_dropped(self, topic: str, count: int = 1) -> None:
        """Record that ``count`` messages of ``topic`` were lost before reaching the writer.

        A recorder calls this for messages it could not keep (queue overflow, sequence gaps);
        the totals are stored in ``metadata.yaml`` ``custom_data["clutch_ros.dropped"]`` as
        ``/topic=n,...`` so a bag says itself what it is missing.
        """
        name = topic_name(topic, self.namespace)
        self.dropped[name] = self.dropped.get(name, 0) + int(count)

    def _connection(self, topic: str) -> tuple[str, Any]:
        name = topic if topic in self._conns else topic_name(topic, self.namespace)
        try:
            return name, self._conns[name]
        except KeyError:
            raise BagError(self.path, f"topic {name} was not added before writing") from None

    def write(self, topic: str, timestamp_ns: int, msg: Any) -> None:
        """Serialize ``msg`` (a rosbags message of the topic's type) and write it.

        Args:
            topic: a topic declared with :meth:`add_topic`.
            timestamp_ns: receive time stored in the bag [ns since epoch].
            msg: the message.

        Raises:
            MessageFieldError: the message does not serialize as the topic's type.

        """
        name, _ = self._connection(topic)
        try:
            data = self.store.serialize_cdr(msg, self._types[name])
        except (struct.error, AttributeError, TypeError, ValueError, KeyError) as err:
            raise MessageFieldError(
                self.path, f"cannot serialize message for {name} as {self._types[name]}: {err}"
            ) from err
        self.write_raw(name, timestamp_ns, data)

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Write an already CDR-serialized message (e.g. from an rclpy raw subscription).

        Args:
            topic: a topic declared with :meth:`add_topic`.
            timestamp_ns: receive time stored in the bag [ns since epoch], >= 0.
            data: CDR bytes including the 4-byte encapsulation header.

        """
        name, conn = self._connection(topic)
        if self.closed or self._writer is None:
            raise BagError(self.path, "bag is closed")
        timestamp_ns = int(timestamp_ns)
        if timestamp_ns < 0:
            raise BagError(self.path, f"negative timestamp {timestamp_ns} ns on {name}")
        try:
            self._writer.write(conn, timestamp_ns, data)
        except (OSError, WriterError) as err:
            raise BagError(self.path, f"cannot write to {name}: {err}") from err
        self.written[name] += 1
        if self.first_ns is None or timestamp_ns < self.first_ns:
            self.first_ns = timestamp_ns
        if self.last_ns is None or timestamp_ns > self.last_ns:
            self.last_ns = timestamp_ns


def write_rig_states(
    out_bag: str | Path,
    samples: Iterable[tuple[int, Mapping[str, Any]]],
    *,
    storage: str = "mcap",
    topic: str = interfaces.RIG_STATE.absolute,
    frame_id: str = "rig",
    custom_data: Mapping[str, str] | None = None,
    on_sample: Callable[[int], None] | None = None,
    compression: str = "none",
) -> BagWriter:
    """Write a ``RigState`` bag from ``(stamp_ns, fields)`` samples (the import back end).

    The bag timestamp of each message equals its header stamp. The output is deleted again if
    ``samples`` raises (an import is all or nothing). A CAN-log importer only has to yield
    samples in SI units with :data:`RIG_STATE_TYPE` field names.

    Args:
        out_bag: bag directory to create.
        samples: ``(stamp_ns, {field: value})`` [ns since epoch; SI units].
        storage: ``"mcap"`` or ``"sqlite3"``.
        topic: topic name (stored absolute).
        frame_id: header frame id.
        custom_data: stored in ``metadata.yaml``.
        on_sample: called with the number of messages written so far after each message.
        compression: ``"none"`` or ``"zstd"`` (MCAP chunk compression).

    Returns:
        the closed writer (``written``, ``first_ns``, ``last_ns``).

    """
    writer = BagWriter(
        out_bag,
        storage=storage,
        custom_data=custom_data,
        delete_on_error=True,
        compression=compression,
    )
    with writer:
        name = writer.add_topic(topic, RIG_STATE_TYPE)
        count = 0
        for stamp_ns, fields in samples:
            writer.write(name, stamp_ns, rig_state_msg(stamp_ns, frame_id=frame_id, **fields))
            count += 1
            if on_sample is not None:
                on_sample(count)
    return writer
