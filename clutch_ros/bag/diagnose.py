"""Find out *why* a bag cannot be read: which file is at fault, and where metadata lies.

A rosbag2 bag is a directory with ``metadata.yaml`` and one or more storage files (``.mcap`` or
``.db3``). rosbags trusts ``metadata.yaml`` for the topics and counts it reports and matches its
connections with the storage file's by topic, type *and offered QoS*; a connection whose QoS
differs is silently skipped. These helpers compare both views independently, so readers can
name the culprit file and cause in their errors.
"""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import Reader
from ruamel.yaml import YAML

from clutch_ros.bag.errors import BagCorruptError

__all__ = ["blame_file", "connection_qos", "load_metadata", "storage_connections", "storage_issues"]


def connection_qos(conn: Connection) -> list[Qos]:
    """Return the offered QoS profiles of a rosbag2 connection (empty for other kinds)."""
    ext = conn.ext
    return list(ext.offered_qos_profiles) if isinstance(ext, ConnectionExtRosbag2) else []


def load_metadata(path: Path) -> dict[str, Any] | None:
    """Return ``rosbag2_bagfile_information`` of a bag directory, or None if it does not parse."""
    try:
        data = YAML(typ="safe").load((path / "metadata.yaml").read_text(encoding="utf-8"))
        info = data["rosbag2_bagfile_information"]
    except Exception:  # noqa: BLE001 - any failure means "metadata.yaml is the culprit"
        return None
    return info if isinstance(info, dict) else None


def storage_files(path: Path, meta: dict[str, Any]) -> list[Path]:
    """Return the storage files listed in a bag's metadata."""
    return [path / PurePath(str(f)).name for f in meta.get("relative_file_paths") or []]


def blame_file(path: Path) -> Path:
    """Pick the file to name for a read failure: metadata.yaml, the storage file, or the bag.

    ``metadata.yaml`` if it does not parse; the storage file if there is exactly one;
    otherwise the bag itself (or ``path`` if it is a bare storage file).
    """
    if not path.is_dir():
        return path
    meta = load_metadata(path)
    if meta is None:
        return path / "metadata.yaml"
    files = storage_files(path, meta)
    return files[0] if len(files) == 1 else path


def storage_connections(path: Path) -> list[Connection] | None:
    """Return the connections (with stored counts) of the storage files of a bag directory.

    Each storage file is opened on its own, without ``metadata.yaml``; MCAP counts come from
    its Statistics record (or a scan), sqlite3 counts from the messages table.

    Returns:
        the connections, or None when the storage cannot be inspected on its own
        (whole-file compression).

    Raises:
        BagCorruptError: metadata.yaml or a storage file cannot be parsed.

    """
    meta = load_metadata(path)
    if meta is None:
        raise BagCorruptError(path / "metadata.yaml", "metadata.yaml cannot be parsed")
    if str(meta.get("compression_mode") or "").lower() == "file":
        return None
    conns: list[Connection] = []
    for file in storage_files(path, meta):
        try:
            with Reader(file) as raw:
                conns.extend(raw.connections)
        except Exception as err:  # noqa: BLE001 - foreign errors of a corrupt storage file
            raise BagCorruptError(file, f"storage file cannot be read: {err}") from err
    return conns


def storage_issues(path: Path, declared: list[Connection]) -> list[str]:
    """Describe how the metadata (``declared`` connections) and the storage file(s) disagree.

    Args:
        path: the bag (a bare storage file has no separate metadata: no issues).
        declared: connections as the bag's metadata declares them (rosbags ``connections``).

    Returns:
        one sentence per disagreement (topics, types, counts, QoS); empty if they agree.

    """
    stored = storage_connections(path) if path.is_dir() else None
    if stored is None:
        return []
    issues = []
    for topic in sorted({c.topic for c in declared} | {c.topic for c in stored}):
        mine = [c for c in declared if c.topic == topic]
        theirs = [c for c in stored if c.topic == topic]
        if not theirs:
            issues.append(f"metadata.yaml lists {topic} but the storage has no such topic")
            continue
        if not mine:
            issues.append(f"the storage holds {topic}, which metadata.yaml does not list")
            continue
        if {c.msgtype for c in mine} != {c.msgtype for c in theirs}:
            issues.append(f"{topic}: type differs between metadata.yaml and the storage")
        n_meta, n_store = sum(c.msgcount for c in mine), sum(c.msgcount for c in theirs)
        if n_meta != n_store:
            issues.append(
                f"{topic}: metadata.yaml declares {n_meta} messages, the storage holds {n_store}"
            )
        qos_meta = sorted(str(connection_qos(c)) for c in mine)
        if qos_meta != sorted(str(connection_qos(c)) for c in theirs):
            issues.append(
                f"{topic}: offered QoS differs between metadata.yaml and the storage "
                "(rosbags then silently yields no messages for it)"
            )
    return issues
