"""Findings 5-7 of issue 13 in the CAN layer: bounded counters, flagged NaN, DBC ranges, junk.

Each test reproduces a finding of the hostile-tester report on the assembler and the codec
(the node-level runs are in tests/nodes/test_can_bridge.py).
"""

import math
import struct
import sys

import can
import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.counters import UNKNOWN_ID_CAPACITY
from clutch_ros.canbus.errors import FrameDecodeError

from .test_can_assembler import rig_frames

FF_FRONT_BIT, FF_REAR_BIT, TEMPERATURES_BIT = 1 << 4, 1 << 5, 1 << 2


def _temperatures(lamella_raw: int, oil_raw: int = 4000, t: float = 0.0) -> can.Message:
    """Return a RigTemperatures frame of raw 16-bit signed values (0.01 degC per bit)."""
    return can.Message(arbitration_id=0x110, is_extended_id=False, timestamp=t,
                       data=struct.pack("<hhxxxx", lamella_raw, oil_raw))


def test_only_the_rear_flexiforce_frame_flags_the_front_group(db):
    """Finding 6: ff_voltages held NaN with no stale flag when only FlexiForceRear arrived."""
    assembler = RigStateAssembler(db)
    for msg in rig_frames(db, t=1.0):
        if db.lookup(msg.arbitration_id).name != "FlexiForceFront":
            assembler.feed(msg)
    sample = assembler.snapshot(1.0)
    assert math.isnan(sample.ff_voltages[0]) and sample.ff_voltages[4:] == pytest.approx(
        [0.1, 0.2, 0.3, 0.4])
    assert sample.stale_mask & FF_FRONT_BIT and "ff_front" in sample.stale
    assert not sample.stale_mask & FF_REAR_BIT
    # once the front frame arrives, nothing is NaN and nothing flagged
    front = next(m for m in rig_frames(db, t=1.001)
                 if db.lookup(m.arbitration_id).name == "FlexiForceFront")
    assembler.feed(front)
    sample = assembler.snapshot(1.001)
    assert all(math.isfinite(v) for v in sample.ff_voltages) and sample.stale_mask == 0


def test_values_outside_the_dbc_range_are_flagged_and_not_used(db):
    """Finding 7: a lamella temperature of -326 degC (DBC range -40..320) was published."""
    with pytest.raises(FrameDecodeError) as info:
        db.decode(0x110, _temperatures(-32600).data)
    assert info.value.reason == "range" and info.value.signals == ("LamellaTemperature",)
    assert info.value.values["LamellaTemperature"] == pytest.approx(-326.0)
    assert db.decode(0x110, _temperatures(-32600).data, check_range=False)[
        "LamellaTemperature"] == pytest.approx(-326.0)
    # edges of the range are valid
    assert db.decode(0x110, _temperatures(32000).data)["LamellaTemperature"] == 320.0
    assert db.decode(0x110, _temperatures(-4000).data)["LamellaTemperature"] == -40.0

    assembler = RigStateAssembler(db)
    for msg in rig_frames(db, t=1.0):
        assembler.feed(msg)
    assembler.feed(_temperatures(-32600, t=1.001))
    assembler.feed(_temperatures(32100, t=1.002))  # 321 degC
    sample = assembler.snapshot(1.002)
    assert sample.lamella_temperature == pytest.approx(85.25)  # the last valid value
    assert sample.stale_mask == TEMPERATURES_BIT and sample.stale == ["temperatures"]
    counters = assembler.counters()
    assert counters.decode_errors_by_reason == {"range": 2}
    assert counters.dropped_frames == 0  # no counter on this frame; nothing made up
    assembler.feed(_temperatures(5000, t=1.003))  # valid again: used, flag cleared
    sample = assembler.snapshot(1.003)
    assert sample.lamella_temperature == 50.0 and sample.stale_mask == 0


@pytest.mark.parametrize("msg", [
    can.Message(arbitration_id=0x900, is_extended_id=False, data=b"\x01"),  # 11 bit > 0x7FF
    can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes(12)),  # 12 B, not FD
    can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes(8), dlc=5),  # DLC
    can.Message(arbitration_id=0x20000000, is_extended_id=True, data=b""),
])
def test_invalid_frames_are_counted_not_decoded(db, msg):
    assembler = RigStateAssembler(db)
    assert assembler.feed(msg) is None
    c = assembler.counters()
    assert c.decode_errors_by_reason == {"invalid_frame": 1} and c.unknown_frames == 0
    assert c.data_frames == c.decoded_frames + c.unknown_frames + c.decode_errors
    assert c.per_id == {}


def test_counters_stay_bounded_whatever_the_bus_carries(db):
    """Finding 5: every distinct unknown identifier used to be kept (and reported)."""
    assembler = RigStateAssembler(db)
    msg = can.Message(arbitration_id=0, is_extended_id=True, data=b"\x00")
    for arb in range(50_000):
        msg.arbitration_id = 0x100000 + arb
        assembler.feed(msg)
    c = assembler.counters()
    assert c.unknown_frames == 50_000
    assert len(c.unknown_id_counts) == UNKNOWN_ID_CAPACITY and c.per_id == {}
    assert c.unknown_untracked == 50_000 - UNKNOWN_ID_CAPACITY
    assert sys.getsizeof(assembler._counters.unknown_ids) < 64 * 1024
    text = c.unknown_ids_text()
    assert text.count(":") == 11 and text.endswith(f"IDs: {50_000 - 10} frames"), text
