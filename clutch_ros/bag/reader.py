"""Reading rosbag2 bags with rosbags, robustly, and a fast columnar path for RigState.

:class:`BagReader` yields ``(topic, timestamp_ns, msg)`` for chosen topics and turns every
failure into a :class:`~clutch_ros.bag.errors.BagError` that names the file and the cause:

- missing bag / metadata.yaml                       -> ``BagNotFoundError``
- truncated or garbage storage, unreadable metadata -> ``BagCorruptError`` (naming the storage
  file or ``metadata.yaml`` that failed to parse)
- a topic whose type is not in the typestore, or whose recorded type hash differs from the
  ``.msg`` files here                               -> ``UnknownTypeError``
- metadata.yaml disagreeing with the storage file   -> ``BagMetadataMismatchError``
  (:func:`check_bag`)
- fewer/more messages yielded than declared         -> ``BagCountMismatchError``

The count check matters: rosbags matches the connections of ``metadata.yaml`` with those of the
storage file by topic, type *and offered QoS*, and silently yields nothing for a connection
whose QoS differs. Every full read (no time window) therefore compares the messages yielded per
topic with the count the bag declares, and explains a mismatch from the storage file.

:func:`read_rig_states` is the fast path for offline replay: raw CDR bytes (scanned directly
from uncompressed MCAP, or read through rosbags) are decoded with numpy
(:class:`~clutch_ros.bag.columns.ColumnDecoder`) into :class:`RigStateArrays`
(see :mod:`~clutch_ros.bag.rig_states`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import Reader

from clutch_ros.bag.diagnose import (
    blame_file,
    connection_qos,
    load_metadata,
    storage_files,
    storage_issues,
)
from clutch_ros.bag.errors import (
    BagCorruptError,
    BagCountMismatchError,
    BagError,
    BagMetadataMismatchError,
    BagNotFoundError,
    UnknownTypeError,
)
from clutch_ros.bag.typestore import (
    ADDED_FIELDS,
    Typestore,
    clutch_typestore,
    legacy_typestore,
    topic_name,
)

__all__ = [
    "BagMessage",
    "BagReader",
    "TopicInfo",
    "check_bag",
    "open_bag",
]


class TopicInfo(NamedTuple):
    """A topic of a bag: type, message count declared [messages] and offered QoS profiles."""

    topic: str
    typename: str
    count: int  # type: ignore[assignment]  # the field shadows tuple.count (kept: public API)
    qos: list[Qos]


class BagMessage(NamedTuple):
    """One message read from a bag: topic, bag timestamp [ns since epoch], message or bytes."""

    topic: str
    timestamp_ns: int
    msg: Any


class BagReader:
    """Read a rosbag2 bag (directory, or a bare ``.mcap`` / ``.db3`` file).

    Args:
        path: bag directory or storage file.
        store: typestore (default :func:`~clutch_ros.bag.typestore.clutch_typestore`).
        verify: on open, compare metadata.yaml with the storage file (:func:`check_bag`).

    Use as a context manager, or call :meth:`open` / :meth:`close`.
    """

    def __init__(self, path: str | Path, *, store: Typestore | None = None, verify: bool = False):
        self.path = Path(path)
        self.store = store or clutch_typestore()
        self._default_store = store is None
        # connection id -> the store of its older definition (typestore.ADDED_FIELDS)
        self._conn_store: dict[int, Typestore] = {}
        self.verify = verify
        self._reader: Reader | None = None
        self._hashes: dict[str, str] = {}

    # -- lifecycle ---------------------------------------------------------------------------
    def open(self) -> BagReader:
        """Open the bag (reads metadata and the storage index).

        Raises:
            BagNotFoundError: no such bag, or no metadata.yaml in the directory.
            BagCorruptError: metadata or storage cannot be parsed (names the file at fault).
            BagMetadataMismatchError: ``verify`` and metadata.yaml disagrees with the storage.

        """
        if self._reader is not None:
            return self
        if not self.path.exists():
            raise BagNotFoundError(self.path, "no such bag")
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            raise BagNotFoundError(
                self.path,
                "no metadata.yaml: not a rosbag2 bag, or an unfinished recording "
                "(`ros2 bag reindex` rebuilds it)",
            )
        meta = load_metadata(self.path) if self.path.is_dir() else None
        for file in storage_files(self.path, meta) if meta else []:
            if not file.exists():
                raise BagNotFoundError(file, "storage file listed in metadata.yaml is missing")
        try:
            reader = Reader(self.path)
            reader.open()
        except PermissionError as err:
            raise BagError(self.path, f"permission denied: {err}") from err
        except Exception as err:  # noqa: BLE001 - rosbags raises many kinds on corrupt input
            raise BagCorruptError(blame_file(self.path), f"cannot open bag: {err}") from err
        self._reader = reader
        if self.verify:
            try:
                check_bag(self.path, store=self.store, _reader=self)
            except BaseException:
                self.close()
                raise
        return self

    def close(self) -> None:
        """Close the bag."""
        reader, self._reader = self._reader, None
        if reader is not None:
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a broken file must not raise
                pass

    def __enter__(self) -> BagReader:
        return self.open()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- metadata ----------------------------------------------------------------------------
    @property
    def reader(self) -> Reader:
        """The underlying open rosbags reader."""
        if self._reader is None:
            raise BagError(self.path, "bag is not open")
        return self._reader

    @property
    def connections(self) -> list[Connection]:
        """Return the rosbags connections of the bag (counts as declared by the bag)."""
        return list(self.reader.connections)

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topics by absolute name, with type, declared count [messages] and offered QoS."""
        out: dict[str, TopicInfo] = {}
        for conn in self.reader.connections:
            old = out.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            qos = (old.qos if old else []) + connection_qos(conn)
            out[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count, qos)
        return out

    @property
    def message_count(self) -> int:
        """Total number of messages the bag declares [messages]."""
        return int(self.reader.message_count)

    @property
    def start_ns(self) -> int:
        """Timestamp of the first message [ns since epoch]."""
        return int(self.reader.start_time)

    @property
    def end_ns(self) -> int:
        """Timestamp of the last message [ns since epoch]."""
        return int(self.reader.end_time) - 1 if self.message_count else 0

    @property
    def custom_data(self) -> dict[str, str]:
        """``custom_data`` of metadata.yaml (empty for bare storage files)."""
        storage = self.reader.storage
        custom = getattr(getattr(storage, "metadata", None), "custom", None)
        return dict(custom or {})

    # -- messages ----------------------------------------------------------------------------
    def _select(self, topics: Iterable[str] | str | None) -> list[Connection]:
        conns = self.reader.connections
        if topics is None:
            return list(conns)
        wanted = {topic_name(t) for t in ([topics] if isinstance(topics, str) else topics)}
        missing = wanted - {c.topic for c in conns}
        if missing:
            have = ", ".join(sorted({c.topic for c in conns})) or "none"
            raise BagError(
                self.path, f"topic(s) {', '.join(sorted(missing))} not in bag (topics: {have})"
            )
        return [c for c in conns if c.topic in wanted]

    def check_types(self, topics: Iterable[str] | str | None = None) -> None:
        """Raise ``UnknownTypeError`` unless every selected topic's type is known and equal.

        (:meth:`messages` checks this itself unless ``raw``.)
        """
        for conn in self._select(topics):
            self._check_type(conn)

    def _check_type(self, conn: Connection) -> None:
        typename = conn.msgtype
        if typename not in self.store.types:
            raise UnknownTypeError(
                self.path,
                f"topic {conn.topic} has type {typename}, which is not in the typestore "
                "(clutch_msgs .msg files plus the ROS 2 base distribution)",
                typename=typename,
            )
        digest = conn.digest or ""
        if digest.startswith("RIHS01_"):
            ours = self._hashes.get(typename)
            if ours is None:
                ours = self._hashes[typename] = self.store.hash_rihs01(typename)
            if ours != digest and self._is_legacy(conn, typename, digest):
                return
            if ours != digest:
                raise UnknownTypeError(
                    self.path,
                    f"topic {conn.topic}: the bag's {typename} ({digest}) differs from the "
                    f"definition in this package ({ours}); regenerate or convert the bag",
                    typename=typename,
                )

    def store_for(self, conn: Connection) -> Typestore:
        """Return the typestore that decodes ``conn`` (checked by :meth:`check_types`)."""
        return self._conn_store.get(conn.id, self.store)

    def _is_legacy(self, conn: Connection, typename: str, digest: str) -> bool:
        """Return True (and remember it) when ``conn`` has the definition before ADDED_FIELDS."""
        if not self._default_store or typename not in ADDED_FIELDS:
            return False
        legacy = legacy_typestore()
        if legacy.hash_rihs01(typename) != digest:
            return False
        self._conn_store[conn.id] = legacy
        return True

    def messages(
        self,
        topics: Iterable[str] | str | None = None,
        *,
        raw: bool = False,
        start_ns: int | None = None,
        stop_ns: int | None = None,
    ) -> Iterator[BagMessage]:
        """Yield ``BagMessage(topic, timestamp_ns, msg)`` in timestamp order.

        Args:
            topics: topic names (relative names are taken as ``/name``); None: all topics.
            raw: yield the CDR bytes instead of deserialized messages.
            start_ns: first bag timestamp to include [ns]; disables the count check.
            stop_ns: bag timestamp to stop before [ns]; disables the count check.

        Raises:
            UnknownTypeError: a selected topic's type is unknown (only when deserializing).
            BagCorruptError: storage or message data cannot be decoded.
            BagCountMismatchError: a full read yielded another number of messages than declared.

        """
        conns = self._select(topics)
        if not raw:
            for conn in conns:
                self._check_type(conn)
        if not conns:  # rosbags reads *all* connections when given none
            return
        declared: dict[str, int] = {}
        for conn in conns:
            declared[conn.topic] = declared.get(conn.topic, 0) + conn.msgcount
        seen = dict.fromkeys(declared, 0)
        deserialize = self.store.deserialize_cdr
        try:
            source = self.reader.messages(connections=conns, start=start_ns, stop=stop_ns)
            for conn, timestamp, data in source:
                topic = conn.topic
                seen[topic] += 1
                if raw:
                    yield BagMessage(topic, timestamp, data)
                    continue
                try:
                    store = self._conn_store.get(conn.id)
                    msg = (store.deserialize_cdr(data, conn.msgtype) if store is not None
                           else deserialize(data, conn.msgtype))
                except Exception as err:  # noqa: BLE001 - SerdeError, struct.error, ...
                    raise BagCorruptError(
                        blame_file(self.path),
                        f"message {seen[topic]} on {topic} at {timestamp} ns cannot be "
                        f"decoded as {conn.msgtype}: {err}",
                    ) from err
                yield BagMessage(topic, timestamp, msg)
        except BagError:
            raise
        except Exception as err:  # noqa: BLE001 - rosbags/storage errors mid-read
            hint = ("; `clutch replay --recover` returns the messages before the damage"
                    if "checksum" in str(err).lower() else "")
            raise BagCorruptError(blame_file(self.path),
                                  f"cannot read messages: {err}{hint}") from err
        if start_ns is None and stop_ns is None:
            self._check_counts(declared, seen)

    def _check_counts(self, declared: dict[str, int], seen: dict[str, int]) -> None:
        for topic, expected in declared.items():
            if seen[topic] != expected:
                issues = storage_issues(self.path, self.reader.connections)
                why = f"; {'; '.join(issues)}" if issues else ""
                raise BagCountMismatchError(
                    self.path,
                    f"{topic}: read {seen[topic]} messages but the bag declares {expected}{why}",
                    topic=topic,
                    expected=expected,
                    actual=seen[topic],
                )


def open_bag(
    path: str | Path, *, store: Typestore | None = None, verify: bool = False
) -> BagReader:
    """Open a bag for reading (a :class:`BagReader`, usable in a ``with`` statement)."""
    return BagReader(path, store=store, verify=verify).open()


def check_bag(
    path: str | Path,
    *,
    expected: dict[str, int] | None = None,
    store: Typestore | None = None,
    _reader: BagReader | None = None,
) -> dict[str, int]:
    """Check that metadata.yaml and the storage file agree (and match ``expected`` counts).

    Args:
        path: bag directory.
        expected: messages per topic the caller wrote [messages], e.g. ``BagWriter.written``.
        store: typestore.

    Returns:
        the message count per topic declared by the bag [messages].

    Raises:
        BagMetadataMismatchError: metadata.yaml and storage disagree (topics, types, counts, QoS).
        BagCountMismatchError: the bag's counts differ from ``expected``.

    """
    bag = _reader or BagReader(path, store=store)
    try:
        bag.open()
        counts = {t: info.count for t, info in bag.topics.items()}
        issues = storage_issues(bag.path, bag.reader.connections)
    finally:
        if _reader is None:
            bag.close()
    if issues:
        raise BagMetadataMismatchError(bag.path, "; ".join(issues))
    for topic, n in (expected or {}).items():
        if counts.get(topic, 0) != n:
            raise BagCountMismatchError(
                bag.path,
                f"{topic}: {n} messages written but the bag declares {counts.get(topic, 0)}",
                topic=topic,
                expected=n,
                actual=counts.get(topic, 0),
            )
    return counts
