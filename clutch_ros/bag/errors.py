"""Errors of the bag layer (typestore, writer, reader, CSV import).

Every error names the file it is about and the cause, so the ``clutch`` CLI can print it as
one line. Foreign errors (rosbags, OS, csv, numpy) are wrapped with ``raise ... from err``.

Hierarchy::

    ClutchError
    └── BagError                        anything about a bag or an import (has ``path``)
        ├── BagExistsError              output bag already exists (never overwritten)
        ├── BagNotFoundError            input bag, metadata.yaml or a storage file missing
        ├── BagCorruptError             truncated/garbage storage, bad metadata, bad data
        │   ├── BagMetadataMismatchError  metadata.yaml disagrees with the storage file
        │   ├── FastMcapError           the MCAP layout is broken (fastmcap's direct scan)
        │   ├── CorruptMessageError     a CDR message does not fit its type (columns), has ``index``
        │   └── _DamagedError           private to recover.py: a record or chunk does not validate
        ├── BagCountMismatchError       messages yielded/written != count declared
        ├── UnknownTypeError            type not in the typestore (or defined differently)
        ├── MessageFieldError           building a message: unknown field or bad value
        └── CsvError                    rig CSV problem, with ``line`` and ``column``

``BagCorruptError``, ``BagCountMismatchError`` and ``CsvError`` are also ``DataError``;
``MessageFieldError``, ``FastMcapError``, ``CorruptMessageError`` and ``_DamagedError`` are
also ``ValueError`` (their callers' ``except ValueError`` keep working). ``FastMcapError``,
``CorruptMessageError`` and ``_DamagedError`` carry no path (``path`` is ``None``): the callers
that know the file wrap them in a :class:`BagCorruptError` naming it. They are importable
from their old modules too (``bag.fastmcap``, ``bag.columns``, ``bag.recover``).
"""

from __future__ import annotations

from pathlib import Path

from clutch_ros.errors import ClutchError, DataError

__all__ = [
    "BagCorruptError",
    "BagCountMismatchError",
    "BagError",
    "BagExistsError",
    "BagMetadataMismatchError",
    "BagNotFoundError",
    "CorruptMessageError",
    "CsvError",
    "FastMcapError",
    "MapError",
    "MessageFieldError",
    "UnknownTypeError",
]


class BagError(ClutchError):
    """A bag (or import source) could not be written or read.

    Attributes:
        path: the bag directory or file concerned (``None`` when not file-related).
        cause: the reason, without the path.

    """

    def __init__(self, path: str | Path | None, cause: str):
        self.path = Path(path) if path is not None else None
        self.cause = cause
        super().__init__(f"{self.path}: {cause}" if self.path is not None else cause)


class BagExistsError(BagError):
    """The output bag path exists already; bags are never overwritten."""


class BagNotFoundError(BagError):
    """The input bag, its ``metadata.yaml`` or one of its storage files is missing."""


class BagCorruptError(BagError, DataError):
    """The bag is truncated, contains garbage, or a message cannot be decoded."""


class BagMetadataMismatchError(BagCorruptError):
    """``metadata.yaml`` disagrees with the storage file (topics, counts or QoS)."""


class BagCountMismatchError(BagError, DataError):
    """The number of messages read or written differs from the number declared.

    Attributes:
        topic: the topic whose count differs (``None`` for the bag total).
        expected: the declared count [messages].
        actual: the count seen [messages].

    """

    def __init__(
        self, path: str | Path | None, cause: str, *, topic: str | None, expected: int, actual: int
    ):
        self.topic = topic
        self.expected = expected
        self.actual = actual
        super().__init__(path, cause)


class UnknownTypeError(BagError):
    """A message type is not registered in the typestore, or its definition differs.

    Attributes:
        typename: the ROS 2 type name, e.g. ``clutch_msgs/msg/RigState``.

    """

    def __init__(self, path: str | Path | None, cause: str, *, typename: str):
        self.typename = typename
        super().__init__(path, cause)


class MessageFieldError(BagError, ValueError):
    """A message builder got an unknown field name or a value of the wrong kind."""


class CsvError(BagError, DataError):
    """A rig CSV file cannot be imported.

    Attributes:
        line: 1-based physical line number in the file (``None`` for whole-file problems).
        column: the column name concerned (``None`` when not column-specific).

    """

    def __init__(
        self,
        path: str | Path | None,
        cause: str,
        *,
        line: int | None = None,
        column: str | None = None,
    ):
        self.line = line
        self.column = column
        where = f"line {line}: " if line is not None else ""
        super().__init__(path, f"{where}{cause}")


class FastMcapError(BagCorruptError, ValueError):
    """The file does not follow the MCAP layout (or uses an unsupported compression)."""

    def __init__(self, cause: str, path: str | Path | None = None):
        super().__init__(path, cause)


class CorruptMessageError(BagCorruptError, ValueError):
    """A message of the batch does not fit its type's layout.

    Attributes:
        index: position of the first bad message in the batch.
        cause: the reason, without the position.

    """

    def __init__(self, index: int, cause: str):
        super().__init__(None, f"message {index}: {cause}")
        self.index = index
        self.cause = cause


class _DamagedError(BagCorruptError, ValueError):
    """A record or chunk does not validate (``bag/recover.py`` catches it and skips the region)."""

    def __init__(self, cause: str):
        super().__init__(None, cause)


class MapError(BagError):
    """A channel map is invalid, or a source lacks a channel the map names."""
