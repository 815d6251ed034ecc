"""Crash-safe MCAP chunks: closed on a time limit, with a CRC, flushed (and fsync'd) at once.

rosbags' MCAP writer (the pinned 0.11.9) closes a chunk only once it holds 1 MiB of records
and writes through a buffered file: a recorder killed after 12 s of 200 Hz RigState left a
0-byte file (the header still in the buffer, the first chunk never closed).
:class:`ChunkedMcapWriter` is that writer with three changes:

- a chunk is also closed once its first message is :attr:`ChunkPolicy.interval` [s] old
  (monotonic clock): checked on every write, and by :meth:`ChunkedMcapWriter.close_if_due`,
  which a recorder calls from a timer so a quiet moment does not keep a chunk open;
- each chunk record carries the CRC-32 of its uncompressed records (rosbags writes 0, "not
  computed"), so every reader (rosbags, the ``mcap`` library, ``clutch replay --recover``)
  detects a flipped bit anywhere in a chunk;
- the header at open and each chunk, with its message indexes, are flushed to the operating
  system as soon as they are written (a crash of the process loses only the open chunk) and,
  with :attr:`ChunkPolicy.sync`, fsync'd (a power cut too).

The fsync runs on a thread of its own (:class:`_Syncer`), not on the writer's: an fsync waits
for the disk, and on the recorder's executor thread that wait stalls every callback sharing it.
In a ``clutch demo`` beside two CPU hogs, the process of the recorder and the torque-request
driver stalled for 0.05-0.1 s about once a second, in step with the 1 s chunk closes, and once
for 1.2 s: the requests stopped and the controller went to its fail-safe. The data is with
the operating system before the fsync starts, so a crash or a kill of the process still loses
only the open chunk; a power cut loses the open chunk and the one whose fsync is under way.
An fsync error (a full or failing disk) is raised by the next write, chunk or close of the
writer, so it is never lost either; :attr:`ChunkedMcapWriter.syncs` and
:attr:`~ChunkedMcapWriter.sync_max_s` say how many fsyncs ran and the longest [s].

The file stays the MCAP rosbags writes (schemas and channels inside the chunk that follows
them, message indexes after each chunk, the summary at close). A killed writer leaves a file
without summary or footer: ``clutch replay --recover`` (:mod:`clutch_ros.bag.recover`) reads
it, the open chunk's decodable prefix included when a crash cut it.
"""

from __future__ import annotations

import os
import struct
import threading
import time
import zlib
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapWriter

__all__ = ["ChunkPolicy", "ChunkedMcapWriter", "ChunkedWriter"]

#: Offset of a chunk record's ``uncompressed_crc`` field from the record start: opcode (1),
#: record length (8), message start and end time (8 + 8), uncompressed size (8).
_CRC_AT = 33
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class ChunkPolicy:
    """When chunks are closed and how hard they are pushed to disk.

    Attributes:
        interval: close a chunk once its first message is this old [s]; None: only by size
            (rosbags' 1 MiB of records), for offline writers that do not need it.
        sync: fsync the file after each chunk (and at open and close), not only flush it.

    """

    interval: float | None = None
    sync: bool = False


class _Syncer:
    """Runs fsync of one file descriptor on a daemon thread, on request (module doc).

    Requests made while an fsync runs are merged into the next one (an fsync covers every
    write before it starts). The first error is kept and raised by :meth:`check`.
    """

    def __init__(self, fd: int):
        self._fd = fd
        self._wanted = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._stop = False
        self._error: OSError | None = None
        self.count = 0  # fsyncs done [1]
        self.max_s = 0.0  # longest fsync [s]
        self._thread = threading.Thread(target=self._run, name="mcap-fsync", daemon=True)
        self._thread.start()

    def request(self) -> None:
        """Ask for an fsync of everything written so far (returns at once)."""
        self._idle.clear()
        self._wanted.set()

    def _run(self) -> None:
        while True:
            self._wanted.wait()
            self._wanted.clear()
            if self._stop:
                self._idle.set()
                return
            start = time.monotonic()
            try:
                os.fsync(self._fd)
            except OSError as err:
                self._error = self._error or err
            self.max_s = max(self.max_s, time.monotonic() - start)
            self.count += 1
            if not self._wanted.is_set():
                self._idle.set()

    def check(self) -> None:
        """Raise the first fsync error, if any (once)."""
        err, self._error = self._error, None
        if err is not None:
            raise OSError(err.errno, f"fsync of the chunks written before failed: "
                          f"{err.strerror or err}")

    def stop(self) -> None:
        """Wait for the fsync under way, end the thread, raise a pending error."""
        self._idle.wait()
        self._stop = True
        self._wanted.set()
        self._thread.join()
        self.check()


class ChunkedMcapWriter(McapWriter):
    """rosbags' MCAP storage writer with time-limited, CRC'd, flushed chunks (module doc)."""

    def __init__(self, path: Path, compression: Any, policy: ChunkPolicy | None = None):
        super().__init__(path, compression)
        self.policy = policy or ChunkPolicy()
        self._opened = 0.0  # [s] monotonic time of the open chunk's first message
        #: chunks written so far (closed by size, time or at close) [chunks].
        self.chunks_closed = 0
        self.bio.flush()
        self._syncer = _Syncer(self.bio.fileno()) if self.policy.sync else None
        self._persist()

    @property
    def syncs(self) -> int:
        """Number of fsyncs completed so far [1] (0 without :attr:`ChunkPolicy.sync`)."""
        return self._syncer.count if self._syncer else 0

    @property
    def sync_max_s(self) -> float:
        """The longest fsync so far [s]."""
        return self._syncer.max_s if self._syncer else 0.0

    def _persist(self) -> None:
        self.bio.flush()
        if self._syncer is not None:
            self._syncer.check()
            self._syncer.request()

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        """Write one message; close the chunk when it is full or its time is up."""
        interval = self.policy.interval
        if interval is None:
            super().write(connection, timestamp, data)
            return
        if self._syncer is not None:
            self._syncer.check()
        now = time.monotonic()
        if not self.chunk.msgs:
            self._opened = now
        super().write(connection, timestamp, data)  # closes the chunk at 1 MiB itself
        if self.chunk.msgs and now - self._opened >= interval:
            self.close_chunk()

    def close_if_due(self, ahead: float = 0.0) -> bool:
        """Close the open chunk if it holds messages and is due within ``ahead`` [s].

        A timer calling this every ``ahead`` seconds closes each chunk before its first
        message is :attr:`ChunkPolicy.interval` old. Returns True when a chunk was closed.
        """
        interval = self.policy.interval
        if interval is None or not self.chunk.msgs:
            return False
        if time.monotonic() - self._opened < interval - ahead:
            return False
        self.close_chunk()
        return True

    def close_chunk(self) -> None:
        """Write the open chunk with its CRC and message indexes, then flush (and fsync)."""
        crc = zlib.crc32(self.chunk.bio.getbuffer())
        start = self.bio.tell()
        super().close_chunk()
        end = self.bio.tell()
        self.bio.seek(start + _CRC_AT)  # rosbags writes 0 (not computed) there
        self.bio.write(_U32.pack(crc))
        self.bio.seek(end)
        self.chunks_closed += 1
        self._persist()

    def close(self, version: int, metadata: str) -> None:
        """Write the summary and footer; with ``sync``, fsync the finished file."""
        if self._syncer is not None:
            self._syncer.stop()  # before the file closes (its descriptor); raises its error
        super().close(version, metadata)
        if self.policy.sync:
            fd = os.open(self.path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


class ChunkedWriter(Writer):
    """rosbags' bag :class:`~rosbags.rosbag2.Writer` whose MCAP files are chunked by ``policy``."""

    def __init__(self, path: Path | str, *, policy: ChunkPolicy, **kwargs: Any):
        super().__init__(path, **kwargs)
        plugins = dict(Writer.STORAGE_PLUGINS)  # per instance: this bag's policy
        plugins[StoragePlugin.MCAP] = partial(  # type: ignore[assignment]  # a factory
            ChunkedMcapWriter, policy=policy)
        self.STORAGE_PLUGINS = plugins
