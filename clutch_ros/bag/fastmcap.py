"""A minimal, fast scan of the message records of one MCAP file, chunk by chunk.

rosbags reads MCAP messages one Python object at a time (~2-3 us per message). For offline
replay only the raw CDR bytes of one or two topics are needed, in bulk: :func:`scan_chunks`
walks the data section once, decompresses each chunk (none, zstd or lz4; CRC checked when
present), and returns per chunk the positions of the wanted messages inside the chunk buffer,
so :class:`~clutch_ros.bag.columns.ColumnDecoder` can decode them in place without per-message
byte copies.

It is only used on files rosbags has opened (and so validated) before, for reading; it does
not replace rosbags. Messages are returned in file order with their log times; callers sort by
log time (stable) to obtain rosbags' order.
"""

from __future__ import annotations

import mmap
import struct
import sys
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from clutch_ros.bag.errors import FastMcapError  # re-exported: its old home

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

__all__ = ["FastMcapError", "MessageBlock", "scan_chunks"]

MAGIC = b"\x89MCAP0\r\n"
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER, _OP_DATA_END = 0x04, 0x05, 0x06, 0x02, 0x0F
_REC = struct.Struct("<BQ")  # opcode, record length
_LEN = struct.Struct("<Q")  # record length
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc


class MessageBlock(NamedTuple):
    """Wanted messages of one chunk: CDR bytes are ``buf[starts[i] : starts[i] + lengths[i]]``.

    ``buf`` has 8 spare zero bytes at its end; ``times`` are log times [ns since epoch].
    """

    buf: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    times: np.ndarray
    channels: np.ndarray


def _lz4(data: bytes) -> bytes:
    from lz4.frame import decompress  # rosbags' own dependency, only needed for lz4 chunks

    return decompress(data)


_DECOMPRESS: dict[str, Callable[[bytes], bytes]] = {
    "": lambda data: data,
    "zstd": zstd.decompress,
    "lz4": _lz4,
}


def _string(buf, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", buf, pos)
    return bytes(buf[pos + 4 : pos + 4 + size]).decode(), pos + 4 + size


def _channel(body: bytes) -> tuple[int, str]:
    (cid,) = struct.unpack_from("<H", body, 0)
    topic, _ = _string(body, 4)
    return cid, topic


class _Scan:
    """Walk records; collect channel topics and the wanted messages of each chunk."""

    def __init__(self, topics: set[str]):
        self.topics = topics
        self.wanted: set[int] = set()

    def channel(self, body: bytes) -> None:
        cid, topic = _channel(body)
        if topic in self.topics:
            self.wanted.add(cid)

    def chunk(self, view: memoryview, whole: np.ndarray, start: int, end: int
              ) -> MessageBlock | None:
        """Scan the chunk record whose body is ``view[start:end]`` (``whole``: the file).

        An uncompressed chunk is scanned in place in the memory-mapped file (no copy): its
        messages are positions in ``whole``, which has the spare bytes the decoder needs
        after every chunk (the summary and footer follow the data section).
        """
        body = view[start:end]
        _, _, size, crc = _CHUNK.unpack_from(body, 0)
        compression, pos = _string(body, 28)
        (length,) = struct.unpack_from("<Q", body, pos)
        pos += 8
        raw = body[pos : pos + length]
        if compression == "" and len(raw) == size and start + pos + size + 32 <= len(whole):
            if crc and zlib.crc32(raw) != crc:
                raise FastMcapError("chunk size or CRC mismatch")
            return self.records(raw, whole, start + pos)
        try:
            data = _DECOMPRESS[compression](bytes(raw))
        except KeyError:
            raise FastMcapError(f"unsupported chunk compression {compression!r}") from None
        except Exception as err:  # noqa: BLE001 - decompressor errors on corrupt data
            raise FastMcapError(f"chunk cannot be decompressed: {err}") from err
        if len(data) != size or (crc and zlib.crc32(data) != crc):
            raise FastMcapError("chunk size or CRC mismatch")
        return self.records(data)

    def records(self, data, buf: np.ndarray | None = None, base: int = 0
                ) -> MessageBlock | None:
        """Locate the wanted messages among the records of one chunk (or a lone message).

        ``data`` holds the records (bytes or a memoryview); ``buf`` is a uint8 array that
        holds them at offset ``base`` with >= 32 spare bytes after them (default: a padded
        copy of ``data``). The positions returned are positions in ``buf``.

        Record boundaries are found by walking the records; a run of message records of one
        size (a fixed-layout message type, the usual case) is verified and taken in one numpy
        step (:func:`_same_size_run`), so the Python loop runs once per run, not per message.
        Record fields are then read for all message records at once with numpy.
        """
        runs: list[np.ndarray] = []  # positions of message records, run by run
        found: list[int] = []  # positions of single message records
        append, unpack = found.append, _LEN.unpack_from
        if buf is None:
            buf, base = np.frombuffer(bytes(data) + bytes(32), dtype=np.uint8), 0
        pos, end = 0, len(data)
        while pos < end:
            if pos + 9 > end:
                raise FastMcapError("truncated record in chunk")
            op = data[pos]
            (size,) = unpack(data, pos + 1)
            if op == _OP_MESSAGE:
                run = _same_size_run(buf, base + pos, 9 + size, base + end)
                if run is not None:
                    if found:
                        runs.append(np.array(found, dtype=np.int64))
                        found.clear()
                    runs.append(run)
                    pos += len(run) * (9 + size)
                    continue
                append(base + pos)
            elif op == _OP_CHANNEL:
                self.channel(bytes(data[pos + 9 : pos + 9 + size]))
            pos += 9 + size
        if pos != end:
            raise FastMcapError("record overruns its chunk")
        if found:
            runs.append(np.array(found, dtype=np.int64))
        if not runs or not self.wanted:
            return None
        at = runs[0] if len(runs) == 1 else np.concatenate(runs)
        size = _field(buf, at + 1, "<u8").astype(np.int64)
        if (size < 22).any():
            raise FastMcapError(f"message record of {int(size.min())} bytes in chunk")
        chans = _field(buf, at + 9, "<u2").astype(np.int64)
        keep = np.isin(chans, np.fromiter(self.wanted, dtype=np.int64))
        if not keep.any():
            return None
        at, size, chans = at[keep], size[keep], chans[keep]
        times = _field(buf, at + 15, "<u8").astype(np.int64)
        return MessageBlock(buf, at + 31, size - 22, times, chans)


#: Shortest run of equal-size message records worth checking with numpy.
_MIN_RUN = 16


def _same_size_run(buf: np.ndarray, pos: int, stride: int, end: int) -> np.ndarray | None:
    """Positions of the run of message records of length ``stride`` starting at ``pos``.

    The record at ``pos`` is a message record of ``stride`` bytes (header included). The
    records that would follow at the same stride are checked at once (opcode and length
    field); the run ends before the first one that differs, or at ``end``. Every position
    returned is a record boundary the record-by-record walk would also reach. None when the
    run would be shorter than :data:`_MIN_RUN` (the walk is as fast then).
    """
    count = (end - pos) // stride
    if count < _MIN_RUN:
        return None
    rows = _rows(buf, pos, stride, count)
    same = (rows[:, 0] == _OP_MESSAGE) & (_column(rows, 1, "<u8") == stride - 9)
    if not same.all():
        count = int(np.argmin(same))  # same[0] is true: count >= 1
        if count < _MIN_RUN:
            return None
    return pos + stride * np.arange(count, dtype=np.int64)


def _rows(buf: np.ndarray, pos: int, stride: int, count: int) -> np.ndarray:
    """``count`` records of ``stride`` bytes from ``pos`` as a strided (count, stride) view."""
    return np.lib.stride_tricks.as_strided(buf[pos:], shape=(count, stride),
                                           strides=(stride, 1), writeable=False)


def _column(rows: np.ndarray, offset: int, dtype: str) -> np.ndarray:
    """Field ``dtype`` at byte ``offset`` of every row of a strided record view (a copy)."""
    width = np.dtype(dtype).itemsize
    return np.ascontiguousarray(rows[:, offset : offset + width]).view(dtype).reshape(-1)


def _field(buf: np.ndarray, pos: np.ndarray, dtype: str) -> np.ndarray:
    """Read one little-endian field of type ``dtype`` at each position of ``pos`` in ``buf``.

    Equally spaced positions (a run of equal records) are read through a strided view, one
    copy; others by a gather.
    """
    width = np.dtype(dtype).itemsize
    count = len(pos)
    if count > 1:
        stride = int(pos[1] - pos[0])
        if stride >= width and int(pos[-1] - pos[0]) == stride * (count - 1) and \
                (count == 2 or (np.diff(pos) == stride).all()):
            return _column(_rows(buf, int(pos[0]), stride, count), 0, dtype)
    return buf[pos[:, None] + np.arange(width)].view(dtype).reshape(-1)


def scan_chunks(path: Path, topics: set[str]) -> Iterator[MessageBlock]:
    """Yield, per chunk (or top-level message), the messages published on ``topics``.

    The file is memory-mapped: uncompressed chunks are scanned and decoded in place. The
    mapping is released when the last block referring to it is gone.

    Raises:
        FastMcapError: not MCAP, truncated, corrupt chunk, unsupported compression.

    """
    scan = _Scan(topics)
    with path.open("rb") as fh:
        if fh.read(8) != MAGIC:
            raise FastMcapError("not an MCAP file (bad magic)")
        mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    view = memoryview(mapped)
    whole = np.frombuffer(mapped, dtype=np.uint8)
    total = len(whole)
    pos = 8
    while True:
        if pos >= total:
            raise FastMcapError("no data end or footer record (truncated file)")
        if pos + 9 > total:
            raise FastMcapError(f"truncated record header at offset {pos}")
        op, size = _REC.unpack_from(view, pos)
        start, end = pos + 9, pos + 9 + size
        if op in {_OP_DATA_END, _OP_FOOTER}:
            return
        if end > total:
            raise FastMcapError(f"truncated record {op:#x} at offset {start}")
        pos = end
        if op == _OP_CHANNEL:
            scan.channel(bytes(view[start:end]))
            continue
        if op == _OP_CHUNK:
            block = scan.chunk(view, whole, start, end)
        elif op == _OP_MESSAGE:
            block = scan.records(view[start - 9 : end])
        else:
            continue
        if block is not None:
            yield block
