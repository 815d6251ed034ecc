"""The rig DBC: strict loading, SI round trips, counter and checksum."""

import math
import random

import can
import cantools
import pytest

from clutch_ros.canbus.dbc import (
    RigDatabase,
    counter_gap,
    crc8_sae_j1850,
    default_dbc_path,
    format_frame_key,
    frame_key,
)
from clutch_ros.canbus.errors import CanError, DbcError, EncodeError, FrameDecodeError
from clutch_ros.errors import ClutchError, ConfigError

EXPECTED_FRAMES = {
    # name: (id, cycle time [s], E2E)
    "PumpRequest": (0x080, 0.010, True),
    "PumpStatus": (0x081, 0.010, True),
    "RigFast": (0x100, 0.001, False),
    "RigSpeed": (0x101, 0.001, False),
    "RigTemperatures": (0x110, 0.100, False),
    "FlexiForceFront": (0x120, 0.010, False),
    "FlexiForceRear": (0x121, 0.010, False),
    "WheelSpeeds": (0x130, 0.010, False),
    "TorqueRequest": (0x140, 0.010, False),
}


def test_dbc_loads_strictly_with_cycle_times():
    raw = cantools.database.load_file(str(default_dbc_path()), strict=True)
    assert {m.name for m in raw.messages} == set(EXPECTED_FRAMES)
    db = RigDatabase()
    for name, (frame_id, cycle, e2e) in EXPECTED_FRAMES.items():
        spec = db.frame(name)
        assert spec.frame_id == frame_id and not spec.is_extended
        assert spec.length == 8
        assert spec.cycle_time == pytest.approx(cycle)
        assert spec.e2e is e2e
        if e2e:
            assert spec.counter_signal and spec.checksum_signal


def test_units_are_converted_to_si(db):
    assert db.signal("ActuatingPressure").si_unit == "Pa"
    assert db.signal("ActuatingPressure").resolution == pytest.approx(100.0)
    assert db.signal("InputShaftSpeed").si_unit == "rad/s"
    assert db.signal("InputShaftSpeed").resolution == pytest.approx(0.001 * math.pi / 30)
    assert db.signal("MeasuredTorque").si_unit == "N m"
    assert db.signal("LamellaTemperature").si_unit == "degC"
    assert db.signal("FF_Rear4").si_unit == "V"
    assert db.signal("PumpSts_Current").si_unit == "A"
    assert db.signal("WheelSpeedRR").si_unit == "rad/s"
    # 10 bar / 60 rpm on the bus -> 1e6 Pa / 2 pi rad/s
    msg = db.make_message("RigFast", {"ActuatingPressure": 1e6, "MeasuredTorque": -12.3,
                                      "MeasuredTorqueValid": 1}, counter=0)
    assert msg.data[0:2] == (10000).to_bytes(2, "little")
    msg = db.make_message("RigSpeed", {"InputShaftSpeed": 2 * math.pi,
                                       "OutputShaftSpeed": 0.0}, counter=0)
    assert int.from_bytes(msg.data[0:3], "little", signed=True) == 60000


def _random_values(rng, spec, edge=None):
    values = {}
    for sig in spec.signals:
        if sig.name == spec.checksum_signal:
            continue
        if edge is not None:
            values[sig.name] = getattr(sig, edge)
        elif sig.resolution == 1.0:
            values[sig.name] = rng.randint(int(sig.minimum), int(sig.maximum))
        else:
            values[sig.name] = rng.uniform(sig.minimum, sig.maximum)
        if sig.resolution == 1.0:
            values[sig.name] = int(values[sig.name])
    return values


@pytest.mark.parametrize("seed", range(20))
def test_every_signal_round_trips_within_resolution(db, seed):
    rng = random.Random(seed)
    edge = {0: "minimum", 1: "maximum"}.get(seed)
    for spec in db.frames:
        values = _random_values(rng, spec, edge)
        decoded = db.decode(spec.frame_id, db.encode(spec.name, values))
        assert set(decoded) == {s.name for s in spec.signals}
        for name, value in values.items():
            tol = db.signal(name).resolution * 0.5 * (1 + 1e-9)
            assert abs(decoded[name] - value) <= tol, (spec.name, name, value, decoded[name])


def test_crc8_sae_j1850_reference_values():
    assert crc8_sae_j1850(b"123456789") == 0x4B  # catalogue check value of CRC-8/SAE-J1850
    assert crc8_sae_j1850(b"") == 0x00
    assert crc8_sae_j1850(b"\x00\x00\x00\x00") == 0x59  # AUTOSAR SWS CRC library example


def test_decode_errors_have_reasons(db):
    with pytest.raises(FrameDecodeError) as info:
        db.decode(0x7FF, bytes(8))
    assert info.value.reason == "unknown"
    with pytest.raises(FrameDecodeError) as info:
        db.decode(0x100, bytes(8), is_extended=True)  # same number, 29-bit: another frame
    assert info.value.reason == "unknown"
    with pytest.raises(FrameDecodeError) as info:
        db.decode(0x100, bytes(7))
    assert info.value.reason == "dlc"
    with pytest.raises(FrameDecodeError):
        db.decode_message(can.Message(arbitration_id=0x100, is_remote_frame=True, dlc=8))
    assert isinstance(info.value, CanError) and isinstance(info.value, ClutchError)


def test_encode_rejects_bad_values(db):
    good = {"ActuatingPressure": 1e5, "MeasuredTorque": 1.0, "MeasuredTorqueValid": 1}
    db.encode("RigFast", good, counter=1)
    with pytest.raises(EncodeError, match="not finite"):
        db.encode("RigFast", {**good, "MeasuredTorque": math.nan}, counter=1)
    with pytest.raises(EncodeError):
        db.encode("RigFast", {**good, "ActuatingPressure": 70e5}, counter=1)
    with pytest.raises(EncodeError, match="unknown signal"):
        db.encode("RigFast", {**good, "Bogus": 1.0}, counter=1)
    with pytest.raises(EncodeError, match="MeasuredTorque"):
        db.encode("RigFast", {"ActuatingPressure": 1e5}, counter=1)
    with pytest.raises(EncodeError, match="checksum"):
        db.encode("PumpRequest", {"PumpReq_Pressure": 1e5, "PumpReq_Checksum": 0}, counter=1)
    with pytest.raises(EncodeError, match="no rolling counter"):
        db.encode("TorqueRequest", {"TorqueRequest": 5.0}, counter=1)
    with pytest.raises(DbcError):
        db.encode("NoSuchFrame", {})


def test_dbc_errors_name_the_file(tmp_path):
    missing = tmp_path / "missing.dbc"
    with pytest.raises(DbcError, match="missing.dbc"):
        RigDatabase(missing)
    broken = tmp_path / "broken.dbc"
    broken.write_text("BO_ 1 X 8 N\n SG_ A : 0|8@1+ (1,0) [0|1]\n")
    with pytest.raises(DbcError, match="broken.dbc"):
        RigDatabase(broken)
    overlap = tmp_path / "overlap.dbc"  # only strict loading rejects overlapping signals
    overlap.write_text(
        'VERSION ""\nBO_ 1 X: 8 N\n SG_ A : 0|8@1+ (1,0) [0|1] "" N\n'
        ' SG_ B : 4|8@1+ (1,0) [0|1] "" N\n'
    )
    cantools.database.load_file(str(overlap), strict=False)
    with pytest.raises(DbcError, match="overlap.dbc.*overlapping"):
        RigDatabase(overlap)
    text = default_dbc_path().read_text()
    furlong = tmp_path / "units.dbc"
    furlong.write_text(text.replace('"degC"', '"furlong"', 1))
    with pytest.raises(DbcError, match="furlong"):
        RigDatabase(furlong)
    no_crc = tmp_path / "no_crc.dbc"
    no_crc.write_text(text.replace("SG_ PumpReq_Checksum : 0|8", "SG_ PumpReq_Chk : 0|8"))
    with pytest.raises(DbcError, match="PumpRequest"):
        RigDatabase(no_crc)
    assert issubclass(DbcError, ConfigError)


def test_counter_gap_and_keys():
    assert counter_gap(14, 15) == 0
    assert counter_gap(15, 0) == 0
    assert counter_gap(15, 2) == 2
    assert counter_gap(3, 3) == 15
    assert format_frame_key(frame_key(0x100)) == "0x100"
    assert format_frame_key(frame_key(0x18EBFF00, True)) == "0x18EBFF00x"
