"""Recover every message of a damaged MCAP bag up to the damage, and say what was lost.

A truncated recording (the recorder killed, a power cut, a disk full) or a flipped bit makes
rosbags refuse the whole file. :func:`recover_mcap` walks the file record by record instead
(as ``mcap recover`` and ``ros2 bag reindex`` do): an intact chunk is kept whole; a damaged
or truncated chunk is decompressed as a stream (zstd or lz4 yield the decodable prefix of a
cut or corrupted frame) and its records are kept up to the first one that does not parse or
whose message does not deserialize. A chunk whose CRC (:mod:`clutch_ros.bag.chunked` writes
one) does not match but whose records all parse and decode is kept whole and reported: the
flipped bit is inside a value, where no reader can find it. What was lost is reported
(:class:`Skipped`: file offsets, why, the chunk's message time range when its header is
readable, the messages kept from it and, when its message index survived, the messages lost).
After a record whose length field is damaged the scan resynchronises on the next chunk that
validates. Schemas and channels come from the data section (the summary is missing after a
crash). :func:`recover_bag` writes the recovered messages into a new, complete bag (raw bytes
unchanged, offered QoS from the channels, metadata.yaml and summary rebuilt) and returns the
report; ``clutch replay --recover`` replays that.
"""

from __future__ import annotations

import struct
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import parse_qos

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
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _INDEX, _DATA_END, _FOOTER = (
    0x03, 0x04, 0x05, 0x06, 0x07, 0x0F, 0x02)
_KNOWN = set(range(0x01, 0x10))
_REC = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time
_PIECE = 1 << 14  # [byte] compressed data fed to the decompressor at a time
_Message = tuple[int, int, bytes]  # channel, log time [ns], CDR bytes


@dataclass
class Skipped:
    """One damaged region of the file."""

    offset: int  # [byte] where it starts
    end: int  # [byte] where the scan resumed
    reason: str
    start_ns: int | None = None  # message time range of a damaged chunk [ns], if readable
    end_ns: int | None = None
    messages: int | None = None  # messages lost from it, when its message index survived
    kept: int = 0  # messages recovered from it (the prefix before the damage)

    def as_dict(self) -> dict:
        """Return a JSON-friendly dict (times in s)."""
        return {"offset": self.offset, "bytes": self.end - self.offset, "reason": self.reason,
                "start_s": None if self.start_ns is None else self.start_ns * 1e-9,
                "end_s": None if self.end_ns is None else self.end_ns * 1e-9,
                "messages": self.messages, "kept": self.kept}


@dataclass
class Recovery:
    """What :func:`recover_mcap` found: topics, messages kept, regions damaged."""

    path: Path
    topics: dict[int, tuple[str, str]] = field(default_factory=dict)  # channel -> topic, type
    messages: list[_Message] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)
    declared: dict[str, int] = field(default_factory=dict)  # per topic, from metadata.yaml
    qos: dict[int, str] = field(default_factory=dict)  # channel -> offered QoS (YAML text)

    def counts(self) -> dict[str, int]:
        """Return recovered messages per topic."""
        out: dict[str, int] = {}
        for cid, _, _ in self.messages:
            topic = self.topics.get(cid, (f"<channel {cid}>", ""))[0]
            out[topic] = out.get(topic, 0) + 1
        return out

    def report(self) -> dict:
        """Return the recovery report: recovered and missing messages, damaged regions."""
        got = self.counts()
        missing = {t: n - got.get(t, 0) for t, n in self.declared.items() if n != got.get(t, 0)}
        return {"file": str(self.path), "recovered": got, "declared": self.declared,
                "missing": missing, "skipped": [s.as_dict() for s in self.skipped]}


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", buf, pos)
    if pos + 4 + size > len(buf):
        raise _DamagedError("string overruns its record")
    return buf[pos + 4:pos + 4 + size].decode(), pos + 4 + size


def _lz4() -> Any:
    from lz4.frame import LZ4FrameDecompressor  # lz4 chunks only (rosbags' own dependency)

    return LZ4FrameDecompressor()


_DECOMPRESSORS: dict[str, Callable[[], Any]] = {"zstd": zstd.ZstdDecompressor, "lz4": _lz4}


def _inflate(compression: str, raw: bytes) -> tuple[bytes, str | None]:
    """Decompress what decodes of ``raw``: (output, why it stopped early or None).

    A stream decompressor yields the prefix of a truncated frame. At a decoding error the
    stream is decoded again up to the failing piece and then a byte at a time, so every block
    before the damage is kept.
    """
    if not compression:
        return raw, None
    make = _DECOMPRESSORS.get(compression)
    if make is None:
        return b"", f"unknown compression {compression!r}"
    dec, out, at, step = make(), bytearray(), 0, _PIECE
    while at < len(raw) and not dec.eof:
        piece = raw[at:at + step]
        try:
            out += dec.decompress(piece)
        except Exception as err:  # noqa: BLE001 - any decompressor error is damage
            if step == 1:
                return bytes(out), f"{compression}: {err}"
            dec, step = make(), 1
            out = bytearray(dec.decompress(raw[:at]))
            continue
        at += len(piece)
    if not dec.eof:
        return bytes(out), f"{compression}: the compressed data ends early"
    return bytes(out), None


class _Scanner:
    def __init__(self, data: bytes, store: Typestore):
        self.data, self.store = data, store
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[int, str, str]] = {}  # id -> schema, topic, QoS text

    @staticmethod
    def parse_meta(op: int, body: bytes, schemas: dict, channels: dict) -> None:
        if op == _SCHEMA:
            (sid,) = struct.unpack_from("<H", body, 0)
            schemas[sid] = _string(body, 2)[0]
        elif op == _CHANNEL:
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, pos = _string(body, 4)
            _, pos = _string(body, pos)  # message encoding
            channels[cid] = (sid, topic, _channel_qos(body, pos))

    def meta(self, op: int, body: bytes) -> None:
        self.parse_meta(op, body, self.schemas, self.channels)

    def walk(self, raw: bytes, commit: bool) -> tuple[list[_Message], str | None]:
        """Return the messages of chunk records ``raw`` up to the first bad one, and why.

        Schemas and channels defined in the chunk apply to its messages; ``commit`` adds
        them to the file's (a resynchronisation probe does not).
        """
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[int, str, str]] = {}
        msgs: list[_Message] = []
        pos, why = 0, None
        while pos < len(raw):
            if pos + 9 > len(raw):
                why = "a record is cut off"
                break
            op, size = _REC.unpack_from(raw, pos)
            if op not in _KNOWN:
                why = f"bad record (opcode {op:#x}, {size} bytes)"
                break
            if pos + 9 + size > len(raw):
                why = f"a record (opcode {op:#x}, {size} bytes) is cut off"
                break
            rec = raw[pos + 9:pos + 9 + size]
            if op == _MESSAGE:
                why = self._message(rec, schemas, channels, msgs)
            elif op in (_SCHEMA, _CHANNEL):
                try:
                    self.parse_meta(op, rec, schemas, channels)
                except (_DamagedError, struct.error, UnicodeDecodeError) as err:
                    why = f"damaged {op:#x} record: {err}"
            if why:
                break
            pos += 9 + size
        if commit:
            self.schemas.update(schemas)
            self.channels.update(channels)
        return msgs, why

    def _message(self, rec: bytes, schemas: dict, channels: dict, msgs: list) -> str | None:
        """Append the message record ``rec`` to ``msgs`` if it decodes; else say why not."""
        if len(rec) < 22:
            return "short message record"
        cid, _, log_time, _ = _MSG_HEAD.unpack_from(rec, 0)
        channel = channels.get(cid) or self.channels.get(cid)
        if channel is None:
            return f"message on unknown channel {cid}"
        typename = schemas.get(channel[0]) or self.schemas.get(channel[0])
        data = bytes(rec[22:])
        if typename in self.store.types:
            try:
                self.store.deserialize_cdr(data, typename)
            except Exception as err:  # noqa: BLE001 - SerdeError, struct.error ...
                return f"a {typename} message does not decode: {err}"
        msgs.append((cid, log_time, data))
        return None

    def chunk(self, body: bytes, whole: bool, commit: bool = True
              ) -> tuple[list[_Message], str | None]:
        """Return the messages of a chunk body up to the damage, and the damage (or None).

        ``whole``: the body is complete (not cut by the end of the file).
        """
        try:
            _, _, size, crc = _CHUNK_HEAD.unpack_from(body, 0)
            compression, pos = _string(body, 28)
            (length,) = struct.unpack_from("<Q", body, pos)
        except (struct.error, _DamagedError, UnicodeDecodeError) as err:
            return [], f"chunk header: {err}"
        raw = body[pos + 8:pos + 8 + length]
        data, why = _inflate(compression, raw)
        problems = []
        if not whole:
            problems.append(f"the file ends inside it ({len(data)} of {size} record bytes "
                            "decoded)")
        elif pos + 8 + length != len(body):
            problems.append("chunk records overrun the chunk")
        elif why:
            problems.append(why)
        elif len(data) != size:
            problems.append(f"uncompressed size {len(data)} != {size}")
        elif crc and zlib.crc32(data) != crc:
            problems.append("CRC mismatch")
        msgs, cut = self.walk(data, commit)
        if cut and whole and not why:  # (a cut chunk or frame ends in a cut record)
            problems.append(cut)
        return msgs, "; ".join(problems) or None

    def chunk_ok_at(self, pos: int) -> bool:
        """Return True when a whole, valid chunk record starts at ``pos`` (resynchronising)."""
        data = self.data
        if pos + 9 + 40 > len(data) or data[pos] != _CHUNK:
            return False
        (size,) = struct.unpack_from("<Q", data, pos + 1)
        if pos + 9 + size > len(data):
            return False
        return self.chunk(data[pos + 9:pos + 9 + size], True, commit=False)[1] is None

    def resync(self, start: int) -> int:
        pos = start
        while True:
            pos = self.data.find(bytes([_CHUNK]), pos)
            if pos < 0:
                return len(self.data)
            if self.chunk_ok_at(pos):
                return pos
            pos += 1


def _channel_qos(body: bytes, pos: int) -> str:
    """Return the ``offered_qos_profiles`` entry of a channel record's metadata map (or '')."""
    (size,) = struct.unpack_from("<I", body, pos)
    pos, end = pos + 4, pos + 4 + size
    while pos < end:
        key, pos = _string(body, pos)
        value, pos = _string(body, pos)
        if key == "offered_qos_profiles":
            return value
    return ""


def _times(body: bytes) -> tuple[int | None, int | None]:
    try:
        start, end, _, _ = _CHUNK_HEAD.unpack_from(body, 0)
        return start, end
    except struct.error:
        return None, None


def _indexed(data: bytes, pos: int) -> int | None:
    """Messages listed by the message index records at ``pos`` (after a chunk); None if none."""
    count, found = 0, False
    while pos + 15 <= len(data) and data[pos] == _INDEX:
        op, size = _REC.unpack_from(data, pos)
        (length,) = struct.unpack_from("<I", data, pos + 11)
        if pos + 9 + size > len(data) or length % 16:
            break
        count, found, pos = count + length // 16, True, pos + 9 + size
    return count if found else None


def recover_mcap(path: str | Path, store: Typestore | None = None) -> Recovery:
    """Scan one MCAP file; keep every message up to each damage, report every damage."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BagError(path, f"cannot read: {err.strerror or err}") from err
    scan = _Scanner(data, store or clutch_typestore())
    result = Recovery(path)
    kept: list[_Message] = []
    pos = len(MAGIC) if data.startswith(MAGIC) else scan.resync(0)
    if not data.startswith(MAGIC):
        result.skipped.append(Skipped(0, pos, "bad magic"))
    while pos < len(data):
        if pos + 9 > len(data):
            result.skipped.append(Skipped(pos, len(data), "truncated record header"))
            break
        op, size = _REC.unpack_from(data, pos)
        end = pos + 9 + size
        if op == _CHUNK:
            whole = end <= len(data)
            body = data[pos + 9:min(end, len(data))]
            msgs, damage = scan.chunk(body, whole)
            kept.extend(msgs)
            if damage is not None:
                nxt = end if whole and (end == len(data) or data[end] in _KNOWN) \
                    else scan.resync(pos + 1)
                indexed = _indexed(data, end) if whole else None
                start_ns, end_ns = _times(body)
                result.skipped.append(Skipped(
                    pos, nxt, f"{'damaged' if whole else 'truncated'} chunk: {damage}",
                    start_ns, end_ns, None if indexed is None else indexed - len(msgs),
                    len(msgs)))
                pos = nxt
                continue
        elif op not in _KNOWN or end > len(data):
            why = "truncated" if op in _KNOWN else f"unknown opcode {op:#x}"
            nxt = scan.resync(pos + 1)
            result.skipped.append(Skipped(pos, nxt, f"{why} record"))
            pos = nxt
            continue
        elif op in (_SCHEMA, _CHANNEL):
            try:
                scan.meta(op, data[pos + 9:end])
            except (_DamagedError, struct.error, UnicodeDecodeError) as err:
                result.skipped.append(Skipped(pos, end, f"damaged {op:#x} record: {err}"))
        elif op == _MESSAGE and size >= 22:
            cid, _, log_time, _ = _MSG_HEAD.unpack_from(data, pos + 9)
            kept.append((cid, log_time, bytes(data[pos + 9 + 22:end])))
        elif op == _FOOTER:
            break
        pos = end
    for cid, (sid, topic, qos) in scan.channels.items():
        result.topics[cid] = (topic, scan.schemas.get(sid, ""))
        result.qos[cid] = qos
    result.messages = [m for m in kept if m[0] in result.topics]
    orphans = len(kept) - len(result.messages)
    if orphans:
        result.skipped.append(Skipped(0, 0, "messages of channels never declared", None, None,
                                      orphans))
    return result


def _qos(text: str) -> list:
    """Return the offered QoS profiles of a channel (rosbags ``Qos``), [] if unreadable."""
    try:
        return parse_qos(text) if text else []
    except ReaderError:
        return []


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
            names = {cid: writer.add_topic(topic, typename, qos=_qos(rec.qos.get(cid, "")))
                     for cid, (topic, typename) in rec.topics.items() if typename}
            for cid, stamp, data in sorted(rec.messages, key=lambda m: m[1]):
                if cid in names:
                    writer.write_raw(names[cid], stamp, data)
                    total += 1
            reports.append(rec)
    if total == 0:
        raise BagError(bag, "nothing could be recovered (no message before the damage)")
    got: dict[str, int] = {}
    for rec in reports:
        for topic, n in rec.counts().items():
            got[topic] = got.get(topic, 0) + n
    missing = {t: n - got.get(t, 0) for t, n in declared.items() if n != got.get(t, 0)}
    return {"bag": str(bag), "recovered_bag": str(out), "recovered": got, "declared": declared,
            "missing": missing, "skipped": [s.as_dict() for r in reports for s in r.skipped]}
