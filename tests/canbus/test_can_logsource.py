"""LogSource: python-can's Vector sample logs and our own ASC/BLF through the decode path."""

import math
import threading
import time
from pathlib import Path

import can
import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.errors import CanError, LogFileError
from clutch_ros.canbus.logsource import LogSource, supported_suffixes

VECTOR = Path(__file__).resolve().parents[1] / "data" / "vector"
SAMPLE_LOGS = sorted(p for p in VECTOR.iterdir() if p.name.endswith((".asc", ".blf", ".gz")))
BAR = 1e5
RPM = math.pi / 30


def test_sample_logs_are_present():
    names = {p.name for p in SAMPLE_LOGS}
    assert {"logfile.asc", "logfile_errorframes.asc", "test_CanErrorFrameExt.blf",
            "test_CanMessage.blf", "test_CanFdMessage64.blf"} <= names
    assert (VECTOR / "README.md").is_file()


@pytest.mark.parametrize("path", SAMPLE_LOGS, ids=lambda p: p.name)
def test_python_can_sample_logs_run_through(db, path):
    assembler = RigStateAssembler(db)
    source = LogSource(path)
    count = source.feed(assembler)
    reference = list(can.LogReader(path))
    counters = assembler.counters()
    assert count == counters.frames_total == len(reference) > 0
    assert counters.error_frames == sum(m.is_error_frame for m in reference)
    assert counters.data_frames == counters.decoded_frames + counters.unknown_frames + \
        counters.decode_errors
    assert source.first_time == reference[0].timestamp
    assembler.snapshot()  # a RigSample can always be built


def test_logfile_asc_counts(db):
    """python-can's logfile.asc: error, remote, FD and 29-bit frames, IDs unknown to us."""
    assembler = RigStateAssembler(db)
    LogSource(VECTOR / "logfile.asc").feed(assembler)
    c = assembler.counters()
    assert (c.frames_total, c.error_frames, c.remote_frames, c.data_frames) == (20, 4, 4, 12)
    assert c.fd_frames == 3  # 0x300 and 0x4EE data, 0x50005x remote
    assert c.unknown_frames == 12 and c.decoded_frames == 0 and c.decode_errors == 0
    assert c.unknown_ids_text() == "0x18EBFF00x: 8, 0x300: 1, 0x4EE: 1, 0x6F8: 1, 0x6F9: 1"
    assert c.unknown_ids_text(limit=2) == "0x18EBFF00x: 8, 0x300: 1, +3 IDs: 3 frames"
    assert c.per_id[0x100] == 1  # a remote frame with our RigFast id: counted, not decoded


def test_errorframes_logs(db):
    for name, errors in (("logfile_errorframes.asc", 3), ("test_CanErrorFrameExt.blf", 2),
                         ("test_CanErrorFrames.asc", 4)):
        assembler = RigStateAssembler(db)
        LogSource(VECTOR / name).feed(assembler)
        assert assembler.counters().error_frames == errors, name


def rig_log(db, seconds=0.5, t0=1_700_000_000.0):
    """Rig traffic at the DBC cycle times with ramps; returns (messages, truth by time)."""
    messages, truth = [], {}
    for k in range(int(seconds * 1000)):
        t = t0 + k * 0.001
        p = 1e5 + 50 * BAR * k / (seconds * 1000)  # 1 -> 51 bar ramp
        speed = 10 * RPM + k * 0.001
        truth[k] = (p, speed)
        messages.append(db.make_message("RigFast", {"ActuatingPressure": p,
                        "MeasuredTorque": 0.1 * k, "MeasuredTorqueValid": 1},
                        counter=k % 16, timestamp=t))
        messages.append(db.make_message("RigSpeed", {"InputShaftSpeed": speed,
                        "OutputShaftSpeed": 0.0}, counter=k % 16, timestamp=t))
        if k % 10 == 0:
            messages.append(db.make_message("PumpStatus", {
                "PumpSts_State": 2, "PumpSts_ActualPressure": p, "PumpSts_Current": 5.0,
                "PumpSts_FltOverCurrent": 0, "PumpSts_FltOverTemp": 0,
                "PumpSts_FltUnderVoltage": 0, "PumpSts_FltSensor": 0,
                "PumpSts_FltReqTimeout": 0, "PumpSts_FltReqChecksum": 0,
                "PumpSts_FltReqCounter": 0}, counter=(k // 10) % 16, timestamp=t))
            messages.append(db.make_message("TorqueRequest", {"TorqueRequest": 100.0},
                                            timestamp=t))
            messages.append(can.Message(arbitration_id=0x7E0, is_extended_id=False,
                                        data=b"\x02\x01\x0c", timestamp=t))  # foreign id
        if k % 100 == 0:
            messages.append(db.make_message("RigTemperatures", {"LamellaTemperature": 35.0 + k / 10,
                                            "OilTemperature": 30.0}, timestamp=t))
    messages.append(can.Message(is_error_frame=True, arbitration_id=0, timestamp=t0 + 0.25))
    messages.sort(key=lambda m: m.timestamp)
    return messages, truth


@pytest.mark.parametrize("suffix, writer", [(".asc", can.ASCWriter), (".blf", can.BLFWriter)])
def test_own_rig_log_round_trip(db, tmp_path, suffix, writer):
    messages, truth = rig_log(db)
    path = tmp_path / f"rig{suffix}"
    out = writer(path)
    for msg in messages:
        out.on_message_received(msg)
    out.stop()
    assembler = RigStateAssembler(db)
    source = LogSource(path)
    samples = list(source.samples(assembler, period=0.01))
    c = assembler.counters()
    assert c.frames_total == len(messages)
    assert c.unknown_frames == 50 and c.unknown_ids == {0x7E0}
    assert c.error_frames == 1 and c.decode_errors == 0 and c.dropped_frames == 0
    assert c.decoded_frames == len(messages) - 51
    assert 49 <= len(samples) <= 51
    first = source.first_time
    checked = 0
    for sample in samples[5:]:
        k = round((sample.stamp - first) / 0.001)
        p, speed = truth[k]
        assert sample.actuating_pressure == pytest.approx(p, abs=60.0)  # 100 Pa resolution
        assert sample.input_speed == pytest.approx(speed, abs=1e-4)
        assert sample.slip_speed == pytest.approx(speed, abs=1e-4)
        assert sample.measured_torque == pytest.approx(0.1 * k, abs=0.051)
        assert sample.torque_request == pytest.approx(100.0)
        assert sample.pump_current == pytest.approx(5.0)
        assert sample.stale_mask == 0, sample.stale
        checked += 1
    assert checked > 40
    assert samples[-1].lamella_temperature == pytest.approx(35.0 + 400 / 10)


def test_realtime_replay_keeps_timing(db, tmp_path):
    messages, _ = rig_log(db, seconds=0.3)
    path = tmp_path / "short.asc"
    out = can.ASCWriter(path)
    for msg in messages:
        out.on_message_received(msg)
    out.stop()
    start = time.perf_counter()
    LogSource(path).feed(RigStateAssembler(db))
    fast = time.perf_counter() - start
    start = time.perf_counter()
    LogSource(path, realtime=True).feed(RigStateAssembler(db))
    real = time.perf_counter() - start
    assert real >= 0.25  # the log spans 0.299 s
    assert fast < real


def test_truncated_and_corrupt_files(db, tmp_path):
    messages, _ = rig_log(db, seconds=0.2)
    for suffix, writer in ((".asc", can.ASCWriter), (".blf", can.BLFWriter)):
        path = tmp_path / f"good{suffix}"
        out = writer(path)
        for msg in messages:
            out.on_message_received(msg)
        out.stop()
        data = path.read_bytes()
        cut = tmp_path / f"cut{suffix}"
        cut.write_bytes(data[: len(data) * 2 // 3])
        with pytest.raises(LogFileError, match=rf"cut\{suffix}.*truncated"):
            LogSource(cut).feed(RigStateAssembler(db))
    # a truncated ASC can still be read on purpose (a log still being written)
    assembler = RigStateAssembler(db)
    assert LogSource(tmp_path / "cut.asc", check_complete=False).feed(assembler) > 100
    # corrupt BLF object signature, length intact
    data = bytearray((tmp_path / "good.blf").read_bytes())
    data[data.index(b"LOBJ")] = ord("X")
    bad = tmp_path / "corrupt.blf"
    bad.write_bytes(bytes(data))
    with pytest.raises(LogFileError, match="corrupt.blf") as info:
        LogSource(bad).feed(RigStateAssembler(db))
    assert isinstance(info.value, CanError) and info.value.__cause__ is not None
    garbage = tmp_path / "garbage.blf"
    garbage.write_bytes(b"this is not a BLF file at all" * 10)
    with pytest.raises(LogFileError, match="garbage.blf"):
        LogSource(garbage).feed(RigStateAssembler(db))
    with pytest.raises(LogFileError, match="missing.asc.*not found"):
        LogSource(tmp_path / "missing.asc").check()
    other = tmp_path / "notes.xyz"
    other.write_text("hello")
    with pytest.raises(LogFileError, match="unsupported"):
        LogSource(other).check()
    assert ".asc" in supported_suffixes() and ".blf" in supported_suffixes()


def test_stop_event_ends_replay(db, tmp_path):
    messages, _ = rig_log(db, seconds=0.1)
    path = tmp_path / "stop.blf"
    out = can.BLFWriter(path)
    for msg in messages:
        out.on_message_received(msg)
    out.stop()
    stop = threading.Event()
    source = LogSource(path)
    seen = 0
    for _ in source.frames(stop):
        seen += 1
        if seen == 10:
            stop.set()
    assert seen == 10
