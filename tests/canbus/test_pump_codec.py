"""The PumpRequest codec: counter and checksum, strict limits, the direct payload = cantools'."""

import math
import random

import cantools
import pytest

from clutch_ros.canbus.dbc import RigDatabase, crc8_sae_j1850
from clutch_ros.canbus.errors import EncodeError, FrameDecodeError
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.errors import ConfigError


def test_pump_request_counter_and_checksum(db):
    codec = PumpRequestCodec(db)
    for counter in range(16):
        frame = codec.encode(12.3456e5, counter)
        assert frame.arbitration_id == 0x080 and frame.dlc == 8
        assert frame.data[0] == crc8_sae_j1850(frame.data[1:])
        pressure, cnt, ok = codec.decode(frame)
        assert ok and cnt == counter
        assert pressure == pytest.approx(12.3456e5, abs=50.0)


def test_every_single_bit_corruption_is_detected(db):
    codec = PumpRequestCodec(db)
    frame = codec.encode(25e5, 7)
    for byte in range(8):
        for bit in range(8):
            data = bytearray(frame.data)
            data[byte] ^= 1 << bit
            assert codec.decode(bytes(data))[2] is False
    status = bytearray(db.encode("PumpStatus", {
        "PumpSts_State": 2, "PumpSts_ActualPressure": 1e6, "PumpSts_Current": 3.0,
        "PumpSts_FltOverCurrent": 0, "PumpSts_FltOverTemp": 0, "PumpSts_FltUnderVoltage": 0,
        "PumpSts_FltSensor": 0, "PumpSts_FltReqTimeout": 0, "PumpSts_FltReqChecksum": 0,
        "PumpSts_FltReqCounter": 0}, counter=3))
    assert db.decode(0x081, status)["PumpSts_Counter"] == 3
    status[4] ^= 0x10
    with pytest.raises(FrameDecodeError) as info:
        db.decode(0x081, status)
    assert info.value.reason == "checksum"


@pytest.mark.parametrize("pressure", [math.nan, math.inf, -math.inf, -1.0, 60e5 + 100.0, 1e12])
def test_pump_request_encode_is_strict(db, pressure):
    with pytest.raises(EncodeError):
        PumpRequestCodec(db).encode(pressure, 0)


@pytest.mark.parametrize("counter", [-1, 16, 1.5, True, "3"])
def test_bad_counter_rejected(db, counter):
    with pytest.raises(EncodeError):
        PumpRequestCodec(db).encode(1e5, counter)


def test_codec_max_pressure(db):
    codec = PumpRequestCodec(db, max_pressure=40e5 + 37.0)
    assert codec.max_pressure == pytest.approx(40e5)
    assert codec.quantize(1e9) == pytest.approx(40e5)
    assert codec.quantize(math.nan) == 0.0
    with pytest.raises(EncodeError):
        codec.encode(40.01e5, 0)
    with pytest.raises(ConfigError):
        PumpRequestCodec(db, max_pressure=61e5)
    with pytest.raises(ConfigError):
        PumpRequestCodec(db, max_pressure=math.nan)


def test_direct_payload_equals_the_databases_on_every_pressure_step(db):
    """The direct layout gives cantools' payload (via RigDatabase.make_message) bit for bit."""
    codec = PumpRequestCodec(db)
    assert codec._layout is not None  # params/rig.dbc: the direct path is the one in use
    rng = random.Random(5)
    steps = range(codec.max_raw + 1)  # every representable pressure, 0..60 bar in 100 Pa
    for raw in steps:
        counter = raw % 16
        pressure = raw * codec.resolution + rng.uniform(-0.49, 0.49) * codec.resolution
        pressure = min(max(pressure, 0.0), codec.max_pressure)
        fast = codec.encode(pressure, counter, timestamp=raw * 0.01)
        slow = db.make_message("PumpRequest", {"PumpReq_Pressure": codec.quantize(pressure)},
                               counter=counter, timestamp=raw * 0.01)
        assert (fast.arbitration_id, fast.is_extended_id, bytes(fast.data), fast.timestamp) == (
            slow.arbitration_id, slow.is_extended_id, bytes(slow.data), slow.timestamp), raw


def test_other_layouts_go_through_the_database(tmp_path):
    """A big-endian pressure is no direct layout: cantools encodes it, and it round-trips."""
    text = RigDatabase().path.read_text().replace(
        ' SG_ PumpReq_Pressure : 16|16@1+ (0.001,0) [0|60] "bar" PUMP_ECU',
        ' SG_ PumpReq_Pressure : 23|16@0+ (0.001,0) [0|60] "bar" PUMP_ECU')
    assert "23|16@0+" in text
    path = tmp_path / "motorola.dbc"
    path.write_text(text)
    db = RigDatabase(path)
    codec = PumpRequestCodec(db)
    assert codec._layout is None
    frame = codec.encode(12.3456e5, 3)
    reference = cantools.database.load_file(str(path)).get_message_by_name("PumpRequest")
    decoded = reference.decode(bytes(frame.data))
    assert decoded["PumpReq_Counter"] == 3 and decoded["PumpReq_Pressure"] == pytest.approx(12.346)
    assert codec.decode(frame) == (pytest.approx(12.346e5), 3, True)
