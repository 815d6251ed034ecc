"""``clutch replay --recover``: every message up to the damage of a cut or bit-flipped MCAP.

The bag: 40,000 RigState messages (1 kHz, stamps i ms after T0) in several MCAP chunks. The
test finds the chunks itself (a plain MCAP record walk) to know the truth: which messages a
damaged chunk held and its time range. Without ``--recover`` the damaged bag is refused as a
whole; with it, exactly the messages before each damage are replayed (a chunk cut by the end
of the file gives its whole records before the cut) and the report names the damaged region
(offset, messages lost and kept, time range) and the missing count. An unknown type on
/rig_state gives a hint naming ``--topic``, an option replay has.
"""

import json
import struct

import numpy as np
import pytest

from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.typestore import RIG_STATE_TYPE, TORQUE_REQUEST_TYPE
from clutch_ros.bag.writer import BagWriter
from clutch_ros.cli.main import main as clutch

N = 40_000
T0 = 1_700_000_000 * 10**9  # [ns]


def _write(path, typename=RIG_STATE_TYPE):
    stamps = T0 + np.arange(N, dtype=np.int64) * 1_000_000
    with BagWriter(path) as writer:
        topic = writer.add_topic("/rig_state", typename)
        if typename == RIG_STATE_TYPE:
            cols = {"actuating_pressure": np.full(N, 20e5), "lamella_temperature": np.full(N, 40.0),
                    "slip_speed": np.full(N, 1.0), "measured_torque": np.full(N, 500.0),
                    "has_measured_torque": np.ones(N, dtype=bool)}
            ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
        else:
            cols, ser = {"torque": np.zeros(N)}, TemplateSerializer(TORQUE_REQUEST_TYPE)
        write_columns(writer, topic, ser, stamps, cols)
    return stamps


def _chunks(file):
    """Return [(offset, size, start_ns, end_ns)] of the chunk records (a plain walk)."""
    data, pos, out = file.read_bytes(), 8, []
    while pos + 9 <= len(data):
        op, size = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:
            start, end = struct.unpack_from("<QQ", data, pos + 9)
            out.append((pos, size, start, end))
        if op == 0x0F:
            break
        pos += 9 + size
    return out


def _replay(bag, *extra):
    return clutch(["replay", str(bag), "--params", "flexiforce_8", "--json", *extra])


def test_truncated_and_bit_flipped_bags_recover_every_intact_chunk(tmp_path, capsys):
    bag = tmp_path / "run"
    stamps = _write(bag)
    (file,) = bag.glob("*.mcap")
    pristine = file.read_bytes()
    chunks = _chunks(file)
    assert len(chunks) >= 4, "the bag must span several chunks"

    # bit flip: the high byte of the first message record's length inside chunk 2
    off, size, start_ns, end_ns = chunks[2]
    head = 9 + 28 + struct.unpack_from("<I", pristine, off + 9 + 28)[0] + 8  # records start
    flipped = bytearray(pristine)
    flipped[off + head + 1 + 6] ^= 0x10
    file.write_bytes(bytes(flipped))
    capsys.readouterr()
    assert _replay(bag) == 2  # refused as a whole without --recover
    assert "Traceback" not in capsys.readouterr().err
    assert _replay(bag, "--recover") == 0
    out = capsys.readouterr()
    (res,) = json.loads(out.out)
    lost = int(np.count_nonzero((stamps >= start_ns) & (stamps <= end_ns)))
    assert 0 < lost < N
    assert res["samples"] == N - lost
    rec = res["recovery"]
    assert rec["missing"] == {"/rig_state": lost} and rec["recovered"] == {"/rig_state": N - lost}
    (skip,) = rec["skipped"]
    assert skip["offset"] == off and skip["bytes"] == 9 + size
    assert (skip["kept"], skip["messages"]) == (0, lost)  # the flip is in its first record
    assert (skip["start_s"], skip["end_s"]) == (start_ns * 1e-9, end_ns * 1e-9)
    assert "damaged chunk" in skip["reason"] and f"offset {off}" in out.err

    # truncated in the middle of chunk 3: chunks 0..2 intact, chunk 3's first part readable
    off3, size3, start3, end3 = chunks[3]
    cut = off3 + size3 // 2
    file.write_bytes(pristine[:cut])
    assert _replay(bag, "--recover") == 0
    (res,) = json.loads(capsys.readouterr().out)
    head = off3 + 9 + 32 + struct.unpack_from("<I", pristine, off3 + 9 + 28)[0] + 8
    in_part = _whole_messages(pristine[head:cut])  # chunk 3's message records before the cut
    assert 0 < in_part < np.count_nonzero((stamps >= start3) & (stamps <= end3))
    kept = int(np.count_nonzero(stamps < start3)) + in_part
    assert res["samples"] == kept
    assert res["recovery"]["missing"] == {"/rig_state": N - kept}
    skip = res["recovery"]["skipped"][0]
    assert skip["offset"] == off3 and skip["reason"].startswith("truncated chunk")
    assert skip["start_s"] == start3 * 1e-9 and skip["kept"] == in_part


def _whole_messages(records: bytes) -> int:
    """Message records lying wholly in ``records`` (uncompressed chunk records, a plain walk)."""
    pos = count = 0
    while pos + 9 <= len(records):
        op, size = struct.unpack_from("<BQ", records, pos)
        if pos + 9 + size > len(records):
            break
        count += op == 0x05
        pos += 9 + size
    return count


def test_unknown_type_on_rig_state_names_the_topic_option(tmp_path, capsys):
    bag = tmp_path / "foreign"
    _write(bag, TORQUE_REQUEST_TYPE)
    assert _replay(bag) == 2
    err = capsys.readouterr().err
    assert "--topic" in err and err.count("\n") == 1
    with pytest.raises(SystemExit):
        clutch(["replay", "--help"])
    assert "--topic" in capsys.readouterr().out
    assert _replay(bag, "--topic", "/rig_state") == 2
    assert "has type clutch_msgs/msg/TorqueRequest, not RigState" in capsys.readouterr().err
