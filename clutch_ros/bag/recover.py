"""Recover what is intact in a damaged MCAP bag, and say exactly what was skipped.

A truncated recording (the recorder killed, a disk full) or a flipped bit makes rosbags refuse
the whole file. :func:`recover_mcap` walks the file record by record instead: every chunk that
decompresses, passes its CRC (when the writer stored one), parses into whole records and whose
messages all deserialize is kept; a damaged chunk or record is skipped and reported
(:class:`Skipped`: file offsets, the chunk's message time range when its header is readable,
its message count when its records parse, and why). After a record whose length field is
damaged the scan resynchronises on the next chunk that validates. Schemas and channels come
from the data section and, when it survived, the summary section. :func:`recover_bag` writes
the recovered messages into a new, clean bag (raw bytes unchanged) and returns the report;
``clutch replay --recover`` replays that.

Limits: rosbags writes no chunk CRC, so a flipped bit inside a number of an uncompressed chunk
(the message still deserializes) cannot be detected by any reader; flips in lengths, strings,
array sizes or compressed data are.
"""

from __future__ import annotations

import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from clutch_ros.bag.diagnose import load_metadata, storage_files
from clutch_ros.bag.errors import BagError, _DamagedError
from clutch_ros.bag.typestore import Typestore, clutch_typestore
from clutch_ros.bag.writer import BagWriter

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

__all__ = ["Recovery", "Skipped", "recover_bag", "recover_mcap"]

MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END, _FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0F, 0x02
_KNOWN = set(range(0x01, 0x10))
_REC = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time


@dataclass
class Skipped:
    """One skipped region of the file."""

    offset: int  # [byte] where it starts
    end: int  # [byte] where the scan resumed
    reason: str
    start_ns: int | None = None  # message time range of a skipped chunk [ns], if readable
    end_ns: int | None = None
    messages: int | None = None  # message records in it, when its records parse

    def as_dict(self) -> dict:
        """Return a JSON-friendly dict (times in s)."""
        return {"offset": self.offset, "bytes": self.end - self.offset, "reason": self.reason,
                "start_s": None if self.start_ns is None else self.start_ns * 1e-9,
                "end_s": None if self.end_ns is None else self.end_ns * 1e-9,
                "messages": self.messages}


@dataclass
class Recovery:
    """What :func:`recover_mcap` found: topics, messages kept, regions skipped."""

    path: Path
    topics: dict[int, tuple[str, str]] = field(default_factory=dict)  # channel -> topic, type
    messages: list[tuple[int, int, bytes]] = field(default_factory=list)  # channel, ns, data
    skipped: list[Skipped] = field(default_factory=list)
    declared: dict[str, int] = field(default_factory=dict)  # per topic, from metadata.yaml

    def counts(self) -> dict[str, int]:
        """Return recovered messages per topic."""
        out: dict[str, int] = {}
        for cid, _, _ in self.messages:
            topic = self.topics.get(cid, (f"<channel {cid}>", ""))[0]
            out[topic] = out.get(topic, 0) + 1
        return out

    def report(self) -> dict:
        """Return the recovery report: recovered and missing messages, skipped regions."""
        got = self.counts()
        missing = {t: n - got.get(t, 0) for t, n in self.declared.items() if n != got.get(t, 0)}
        return {"file": str(self.path), "recovered": got, "declared": self.declared,
                "missing": missing, "skipped": [s.as_dict() for s in self.skipped]}


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", buf, pos)
    if pos + 4 + size > len(buf):
        raise _DamagedError("string overruns its record")
    return buf[pos + 4:pos + 4 + size].decode(), pos + 4 + size


class _Scanner:
    def __init__(self, data: bytes, store: Typestore):
        self.data, self.store = data, store
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[int, str]] = {}

    def meta(self, op: int, body: bytes) -> None:
        if op == _SCHEMA:
            (sid,) = struct.unpack_from("<H", body, 0)
            self.schemas[sid] = _string(body, 2)[0]
        elif op == _CHANNEL:
            cid, sid = struct.unpack_from("<HH", body, 0)
            self.channels[cid] = (sid, _string(body, 4)[0])

    def chunk(self, body: bytes) -> tuple[list[tuple[int, int, bytes]], list]:
        """Return (messages, meta records) of a chunk body; raise _DamagedError if it is bad."""
        try:
            _, _, size, crc = _CHUNK_HEAD.unpack_from(body, 0)
            compression, pos = _string(body, 28)
            (length,) = struct.unpack_from("<Q", body, pos)
        except struct.error as err:
            raise _DamagedError(f"chunk header: {err}") from err
        raw = body[pos + 8:pos + 8 + length]
        if len(raw) != length or pos + 8 + length != len(body):
            raise _DamagedError("chunk records overrun the chunk")
        if compression == "zstd":
            try:
                raw = zstd.decompress(raw)
            except Exception as err:  # noqa: BLE001 - any decompressor error
                raise _DamagedError(f"zstd: {err}") from err
        elif compression == "lz4":
            from lz4.frame import decompress  # rosbags' own dependency, lz4 chunks only

            try:
                raw = decompress(raw)
            except Exception as err:  # noqa: BLE001 - any decompressor error
                raise _DamagedError(f"lz4: {err}") from err
        elif compression:
            raise _DamagedError(f"unknown compression {compression!r}")
        if len(raw) != size:
            raise _DamagedError(f"uncompressed size {len(raw)} != {size}")
        if crc and zlib.crc32(raw) != crc:
            raise _DamagedError("CRC mismatch")
        msgs, metas, pos = [], [], 0
        while pos < len(raw):
            if pos + 9 > len(raw):
                raise _DamagedError("truncated record in chunk")
            op, rsize = _REC.unpack_from(raw, pos)
            if op not in _KNOWN or pos + 9 + rsize > len(raw):
                raise _DamagedError(f"bad record (opcode {op:#x}, {rsize} bytes) in chunk")
            rec = raw[pos + 9:pos + 9 + rsize]
            if op == _MESSAGE:
                if rsize < 22:
                    raise _DamagedError("short message record")
                cid, _, log_time, _ = _MSG_HEAD.unpack_from(rec, 0)
                msgs.append((cid, log_time, bytes(rec[22:])))
            elif op in (_SCHEMA, _CHANNEL):
                metas.append((op, rec))
            pos += 9 + rsize
        return msgs, metas

    def check_messages(self, msgs) -> None:
        for cid, _, data in msgs:
            typename = self.typename(cid)
            if typename is None:
                raise _DamagedError(f"message on unknown channel {cid}")
            if typename in self.store.types:
                try:
                    self.store.deserialize_cdr(data, typename)
                except Exception as err:  # noqa: BLE001 - SerdeError, struct.error ...
                    raise _DamagedError(f"a {typename} message does not decode: {err}") from err

    def typename(self, cid: int) -> str | None:
        if cid not in self.channels:
            return None
        return self.schemas.get(self.channels[cid][0])

    def chunk_ok_at(self, pos: int) -> bool:
        """Return True when a whole, valid chunk record starts at ``pos`` (resynchronising)."""
        data = self.data
        if pos + 9 + 40 > len(data) or data[pos] != _CHUNK:
            return False
        (size,) = struct.unpack_from("<Q", data, pos + 1)
        if pos + 9 + size > len(data):
            return False
        try:
            self.chunk(data[pos + 9:pos + 9 + size])
        except (_DamagedError, struct.error, UnicodeDecodeError):
            return False
        return True

    def resync(self, start: int) -> int:
        pos = start
        while True:
            pos = self.data.find(bytes([_CHUNK]), pos)
            if pos < 0:
                return len(self.data)
            if self.chunk_ok_at(pos):
                return pos
            pos += 1


def _times(body: bytes) -> tuple[int | None, int | None]:
    try:
        start, end, _, _ = _CHUNK_HEAD.unpack_from(body, 0)
        return start, end
    except struct.error:
        return None, None


def recover_mcap(path: str | Path, store: Typestore | None = None) -> Recovery:
    """Scan one MCAP file; keep every intact chunk, report every skipped region."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BagError(path, f"cannot read: {err.strerror or err}") from err
    scan = _Scanner(data, store or clutch_typestore())
    result = Recovery(path)
    pending: list[tuple[int, int, bytes]] = []  # messages of chunks whose channel came later
    pos = len(MAGIC) if data.startswith(MAGIC) else scan.resync(0)
    if pos == 0 and not data.startswith(MAGIC):
        result.skipped.append(Skipped(0, pos, "bad magic"))
    while pos < len(data):
        if pos + 9 > len(data):
            result.skipped.append(Skipped(pos, len(data), "truncated record header"))
            break
        op, size = _REC.unpack_from(data, pos)
        end = pos + 9 + size
        if op not in _KNOWN or end > len(data):
            body = data[pos + 9:min(end, len(data))]
            start_ns, end_ns = _times(body) if op == _CHUNK else (None, None)
            why = "truncated" if op in _KNOWN else f"unknown opcode {op:#x}"
            nxt = scan.resync(pos + 1)
            result.skipped.append(Skipped(pos, nxt, f"{why} record", start_ns, end_ns))
            pos = nxt
            continue
        body = data[pos + 9:end]
        if op == _CHUNK:
            try:
                msgs, metas = scan.chunk(body)
                for mop, rec in metas:
                    scan.meta(mop, rec)
                scan.check_messages(msgs)
                pending.extend(msgs)
            except (_DamagedError, struct.error, UnicodeDecodeError) as err:
                start_ns, end_ns = _times(body)
                count = _count_messages(scan, body)
                nxt = end if end == len(data) or data[end] in _KNOWN else scan.resync(pos + 1)
                result.skipped.append(Skipped(pos, nxt, f"damaged chunk: {err}", start_ns,
                                              end_ns, count))
                pos = nxt
                continue
        elif op in (_SCHEMA, _CHANNEL):
            try:
                scan.meta(op, body)
            except (_DamagedError, struct.error, UnicodeDecodeError) as err:
                result.skipped.append(Skipped(pos, end, f"damaged {op:#x} record: {err}"))
        elif op == _MESSAGE and size >= 22:
            cid, _, log_time, _ = _MSG_HEAD.unpack_from(body, 0)
            pending.append((cid, log_time, bytes(body[22:])))
        elif op == _FOOTER:
            break
        pos = end
    for cid, (sid, topic) in scan.channels.items():
        result.topics[cid] = (topic, scan.schemas.get(sid, ""))
    result.messages = [m for m in pending if m[0] in result.topics]
    orphans = len(pending) - len(result.messages)
    if orphans:
        result.skipped.append(Skipped(0, 0, "messages of channels never declared", None, None,
                                      orphans))
    return result


def _count_messages(scan: _Scanner, body: bytes) -> int | None:
    """Message records of a damaged chunk whose records still parse (else None)."""
    try:
        return len(scan.chunk(body)[0])
    except (_DamagedError, struct.error, UnicodeDecodeError):
        return None


def recover_bag(bag: str | Path, out: str | Path, store: Typestore | None = None) -> dict:
    """Recover the MCAP storage file(s) of ``bag`` into the new bag ``out``; return the report.

    Raises:
        BagError: ``bag`` has no MCAP file, or nothing could be recovered.

    """
    bag = Path(bag)
    meta = load_metadata(bag) if bag.is_dir() else None
    if bag.is_dir():
        files = [f for f in storage_files(bag, meta) if f.suffix == ".mcap"] if meta else \
            sorted(bag.glob("*.mcap"))
    else:
        files = [bag]
    files = [f for f in files if f.is_file()]
    if not files:
        raise BagError(bag, "--recover reads MCAP storage only; no .mcap file found")
    declared: dict[str, int] = {}
    try:
        for topic in (meta or {}).get("topics_with_message_count", []):
            declared[topic["topic_metadata"]["name"]] = int(topic["message_count"])
    except (KeyError, TypeError, ValueError):  # damaged metadata: no declared counts
        declared = {}
    reports, total = [], 0
    with BagWriter(out, storage="mcap", verify=True) as writer:
        for file in files:
            rec = recover_mcap(file, store)
            names = {cid: writer.add_topic(topic, typename)
                     for cid, (topic, typename) in rec.topics.items() if typename}
            for cid, stamp, data in sorted(rec.messages, key=lambda m: m[1]):
                if cid in names:
                    writer.write_raw(names[cid], stamp, data)
                    total += 1
            reports.append(rec)
    if total == 0:
        raise BagError(bag, "nothing could be recovered (no intact chunk)")
    got: dict[str, int] = {}
    for rec in reports:
        for topic, n in rec.counts().items():
            got[topic] = got.get(topic, 0) + n
    missing = {t: n - got.get(t, 0) for t, n in declared.items() if n != got.get(t, 0)}
    return {"bag": str(bag), "recovered_bag": str(out), "recovered": got, "declared": declared,
            "missing": missing, "skipped": [s.as_dict() for r in reports for s in r.skipped]}
