"""Recovery inside a damaged chunk, and chunks the writer closes on time (crash safety).

The truth is found independently of ``bag/recover.py``: a plain record walk of the pristine
file, and for compressed chunks the ``zstandard`` package (the ``mcap`` library's own zstd
binding) decoding the compressed bytes before the damage as a stream. A message counts as
"before the damage" when its whole record lies in what those bytes decode to.
"""

import struct
import time
import zlib

import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader

from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.recover import recover_bag, recover_mcap
from clutch_ros.bag.typestore import RIG_STATE_TYPE
from clutch_ros.bag.writer import BagWriter

N = 2_000  # RigState messages: about 0.4 MB of records, one chunk
T0 = 1_700_000_000 * 10**9  # [ns]


def _write(path, compression="none", n=N):
    stamps = T0 + np.arange(n, dtype=np.int64) * 5_000_000  # 200 Hz
    with BagWriter(path, compression=compression) as writer:
        topic = writer.add_topic("/rig_state", RIG_STATE_TYPE)
        cols = {"actuating_pressure": 20e5 + np.arange(n), "lamella_temperature": np.full(n, 40.0),
                "slip_speed": np.full(n, 1.0), "measured_torque": np.arange(n, dtype=float),
                "has_measured_torque": np.ones(n, dtype=bool)}
        ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
        write_columns(writer, topic, ser, stamps, cols)
    (file,) = path.glob("*.mcap")
    return file


def _chunks(data):
    """[(offset, size)] of the chunk records of an MCAP file (a plain walk)."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, size = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:
            out.append((pos, size))
        if op == 0x0F:
            break
        pos += 9 + size
    return out


def _records_start(data, off):
    """(file offset of the compressed records, compression) of the chunk at ``off``."""
    (clen,) = struct.unpack_from("<I", data, off + 9 + 28)
    compression = data[off + 9 + 32:off + 9 + 32 + clen].decode()
    return off + 9 + 32 + clen + 8, compression


def _messages(records):
    """[(record end within ``records``, log time, CDR)] of the whole message records."""
    pos, out = 0, []
    while pos + 9 <= len(records):
        op, size = struct.unpack_from("<BQ", records, pos)
        if pos + 9 + size > len(records):
            break
        if op == 0x05:
            log_time = struct.unpack_from("<Q", records, pos + 9 + 6)[0]
            out.append((pos + 9 + size, log_time, records[pos + 9 + 22:pos + 9 + size]))
        pos += 9 + size
    return out


def _single_chunk(file):
    """(file bytes, records start, message records) of a one-chunk uncompressed bag file."""
    data = file.read_bytes()
    (chunk,) = _chunks(data)
    start, _ = _records_start(data, chunk[0])
    return data, start, _messages(data[start:chunk[0] + 9 + chunk[1]])


def _flip(file, data, at, bit):
    flipped = bytearray(data)
    flipped[at] ^= bit
    file.write_bytes(bytes(flipped))


def _recovered(path):
    rec = recover_mcap(path)
    return [(t, data) for _, t, data in rec.messages], rec


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_single_chunk_truncated_at_half_returns_its_first_part(tmp_path, compression):
    file = _write(tmp_path / "bag", compression)
    data = file.read_bytes()
    (chunk,) = _chunks(data)
    start, _ = _records_start(data, chunk[0])
    # half the file; a zstd chunk is a small part of its file (the message index and the
    # summary are most of it): half the chunk
    cut = len(data) // 2 if compression == "none" else chunk[0] + (9 + chunk[1]) // 2
    assert start < cut < chunk[0] + 9 + chunk[1]  # the cut is inside the chunk's records
    if compression == "zstd":
        prefix = zstandard.ZstdDecompressor().decompressobj().decompress(data[start:cut])
    else:
        prefix = data[start:cut]
    truth = [(t, m) for _, t, m in _messages(prefix)]
    assert N // 4 < len(truth) < N  # the first part: a real share, not all

    file.write_bytes(data[:cut])
    got, rec = _recovered(file)
    assert got == truth  # every message of the first part, byte for byte, nothing else
    (skip,) = rec.skipped
    assert skip.offset == chunk[0] and skip.kept == len(truth)
    assert skip.reason.startswith("truncated chunk: the file ends inside it")
    assert (skip.start_ns, skip.end_ns) == (T0, T0 + (N - 1) * 5_000_000)

    report = recover_bag(tmp_path / "bag", tmp_path / "recovered")  # rebuilt: a complete bag
    assert report["recovered"] == {"/rig_state": len(truth)}
    assert (tmp_path / "recovered" / "metadata.yaml").is_file()
    with open(tmp_path / "recovered" / "recovered.mcap", "rb") as fh:
        again = [(m.log_time, m.data) for _, _, m in make_reader(fh).iter_messages()]
    assert again == truth


def test_bit_flip_in_a_record_length_returns_the_messages_before_it(tmp_path):
    file = _write(tmp_path / "bag")
    data, start, msgs = _single_chunk(file)
    k = 1234
    _flip(file, data, start + msgs[k - 1][0] + 1 + 5, 0x40)  # message k's record length
    got, rec = _recovered(file)
    assert got == [(t, m) for _, t, m in msgs[:k]]
    (skip,) = rec.skipped
    assert skip.reason.startswith("damaged chunk: CRC mismatch")  # the writer stored one
    assert (skip.kept, skip.messages) == (k, N - k)  # lost: from the surviving message index


def test_bit_flip_in_a_value_is_reported_and_every_message_kept(tmp_path):
    file = _write(tmp_path / "bag")
    data, start, msgs = _single_chunk(file)
    _flip(file, data, start + msgs[700][0] - 3, 0x01)  # message 700's last field, stale_mask
    got, rec = _recovered(file)
    assert got[:700] == [(t, m) for _, t, m in msgs[:700]]  # everything before the flip
    assert len(got) == N  # records and messages all still decode: kept, and said so
    (skip,) = rec.skipped
    assert skip.reason == "damaged chunk: CRC mismatch" and skip.kept == N


def test_bit_flip_in_compressed_data_returns_what_decodes_before_it(tmp_path):
    file = _write(tmp_path / "bag", "zstd")
    data = file.read_bytes()
    (chunk,) = _chunks(data)
    start, compression = _records_start(data, chunk[0])
    assert compression == "zstd"
    end = chunk[0] + 9 + chunk[1]
    flip = start + (end - start) * 2 // 3
    truth = [(t, m) for _, t, m in _messages(
        zstandard.ZstdDecompressor().decompressobj().decompress(data[start:flip]))]
    assert len(truth) > N // 3
    _flip(file, data, flip, 0x10)
    got, rec = _recovered(file)
    assert got[:len(truth)] == truth  # every message the bytes before the flip hold
    (skip,) = rec.skipped
    assert skip.reason.startswith("damaged chunk") and skip.kept == len(got)


def test_chunks_close_on_time_with_crc_and_are_on_disk_while_writing(tmp_path):
    """A writer with chunk_interval: each chunk is in the file once it is that old."""
    interval = 0.05  # [s]
    path = tmp_path / "live"
    ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
    writer = BagWriter(path, chunk_interval=interval, sync=True).open()
    topic = writer.add_topic("/rig_state", RIG_STATE_TYPE)
    (file,) = path.glob("*.mcap")
    assert file.read_bytes().startswith(b"\x89MCAP0\r\n")  # the header is on disk at once
    sent = []
    for i in range(40):  # 40 messages over about 0.4 s: several time-closed chunks
        stamp = T0 + i * 10_000_000
        write_columns(writer, topic, ser, np.array([stamp]),
                      {"measured_torque": np.array([float(i)])})
        sent.append(stamp)
        time.sleep(0.01)
    time.sleep(interval)
    writer.close_chunk_if_due()
    on_disk = file.read_bytes()  # still open: no summary, no footer, like after a crash
    chunks = _chunks(on_disk)
    assert len(chunks) >= 4
    for off, size in chunks:
        start, _ = _records_start(on_disk, off)
        (crc,) = struct.unpack_from("<I", on_disk, off + 9 + 24)
        assert crc == zlib.crc32(on_disk[start:off + 9 + size]) != 0
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(on_disk)
    got, rec = _recovered(copy)
    assert [t for t, _ in got] == sent and rec.skipped == []  # all of it: every chunk closed
    writer.close()
    with open(file, "rb") as fh:  # the finished file: the mcap library checks every CRC
        reader = make_reader(fh, validate_crcs=True)
        assert [m.log_time for _, _, m in reader.iter_messages()] == sent
        assert reader.get_summary().statistics.chunk_count == len(chunks)
