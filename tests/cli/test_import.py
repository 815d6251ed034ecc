"""``clutch import``: rig CSV, python-can's Vector sample logs and our own rig frames -> bags.

Every case runs the real command in a subprocess (``python -m clutch_ros.cli import ...``):
good inputs give bags whose values are checked against the source, ``--json`` is parsed,
and every bad input gives exactly one stderr line ``clutch import: error: FILE: ...`` naming
the cause (with the line number for CSV rows), exit code 2, no traceback and no bag left.
"""

import json
import math
import subprocess
import sys

import can
import numpy as np
import pytest

from clutch_ros.bag.arrays import read_columns
from clutch_ros.bag.reader import open_bag
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.canbus import RigDatabase
from tests.conftest import REPO

CSV = REPO / "tests" / "data" / "csv"
VECTOR = REPO / "tests" / "data" / "vector"
RPM = 2 * math.pi / 60


def clutch(*args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "clutch_ros.cli", *map(str, args)],
        cwd=REPO, capture_output=True, text=True, timeout=120, env=env,
    )  # fmt: skip


def one_error_line(proc, *parts):
    """Assert exit code 2 and one clean error line holding ``parts``; return the line."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("clutch import: error: "), lines[0]
    for part in parts:
        assert part in lines[0], (part, lines[0])
    return lines[0]


# -- CSV ---------------------------------------------------------------------------------------


def test_csv_to_bag_with_json(tmp_path):
    out = tmp_path / "run"
    proc = clutch("import", CSV / "rig_run.csv", "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)
    assert result == {
        "source": str(CSV / "rig_run.csv"), "bag": str(out), "format": "csv", "messages": 5,
        "duration_s": pytest.approx(0.004), "ignored_columns": [],
    }  # fmt: skip
    rig = read_rig_states(out)
    assert rig.stamp_ns.tolist() == [0, 1_000_000, 2_000_000, 3_000_000, 4_000_000]
    assert np.allclose(rig.actuating_pressure, [0.0, 1.5e5, 10e5, 40e5, 20e5])  # bar -> Pa
    assert np.allclose(rig.slip_speed, np.array([10, 10, 30, 50, -30]) * RPM)  # rpm -> rad/s
    assert rig.has_measured_torque.tolist() == [True, True, False, True, True]


def test_several_csv_files_into_a_directory_in_sqlite3(tmp_path):
    out = tmp_path / "bags"
    proc = clutch("import", CSV / "rig_run.csv", CSV / "rig_run_semicolon.csv", "-o", out,
                  "--storage", "sqlite3")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("5 RigState messages (csv") == 2
    a, b = read_rig_states(out / "rig_run"), read_rig_states(out / "rig_run_semicolon")
    assert np.array_equal(a.actuating_pressure, b.actuating_pressure)
    assert (out / "rig_run" / "rig_run.db3").is_file()


@pytest.mark.parametrize(
    ("name", "parts"),
    [
        ("missing_lamella_temp.csv", ["line 1: missing required column 'lamella_temp_c'"]),
        ("time_goes_back.csv", ["line 5: time does not increase (0.0015 s after 0.002 s)"]),
        ("bad_value.csv", ["line 4: cannot parse '12.5x' as a number in column 'pressure_bar'"]),
        ("empty.csv", ["empty file: no header line"]),
    ],
)
def test_bad_csv_one_line_error_exit_2(tmp_path, name, parts):
    out = tmp_path / "bad"
    line = one_error_line(clutch("import", CSV / name, "-o", out), *parts)
    assert str(CSV / name) in line
    assert not out.exists()  # all or nothing


def test_missing_input_and_existing_output(tmp_path):
    one_error_line(clutch("import", tmp_path / "nope.csv", "-o", tmp_path / "x"), "no such file")
    out = tmp_path / "exists"
    out.mkdir()
    one_error_line(clutch("import", CSV / "rig_run.csv", "-o", out), "exists already")


# -- python-can's Vector sample logs -----------------------------------------------------------


@pytest.mark.parametrize(
    "name", ["logfile_errorframes.asc", "test_CanErrorFrames.asc", "issue_1905.blf"]
)
def test_vector_sample_logs_keep_every_frame(tmp_path, name):
    """No rig frames in these logs: no RigState, but every frame (error frames too) kept."""
    out = tmp_path / "log"
    proc = clutch("import", VECTOR / name, "-o", out, "--frames", "--json")
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)
    frames = list(can.LogReader(VECTOR / name))
    assert result["format"] == "can" and result["messages"] == 0
    assert result["frames"] == result["can_frames"] == len(frames)
    assert result["error_frames"] == sum(f.is_error_frame for f in frames)
    assert result["truncated_fd_frames"] == sum(len(f.data) > 8 for f in frames)
    assert "no RigState sample" in proc.stderr  # a warning, not an error
    cols, bag_ns, _ = read_columns(out, "/can_frames")
    order = np.argsort([f.timestamp for f in frames], kind="stable")
    frames = [frames[i] for i in order]
    assert cols["id"].tolist() == [f.arbitration_id for f in frames]
    assert cols["is_error"].tolist() == [f.is_error_frame for f in frames]
    assert cols["is_extended"].tolist() == [f.is_extended_id for f in frames]
    assert cols["is_rtr"].tolist() == [f.is_remote_frame for f in frames]
    assert cols["dlc"].tolist() == [f.dlc for f in frames]
    for row, frame in zip(cols["data"], frames):
        data = bytes(frame.data[:8])
        assert bytes(row[: len(data)]) == data and not row[len(data) :].any()
    assert np.array_equal(cols["stamp_ns"], bag_ns)
    assert np.allclose(bag_ns / 1e9, [f.timestamp for f in frames], atol=1e-6)
    with open_bag(out, verify=True) as bag:
        assert bag.topics["/rig_state"].count == 0


def test_vector_logs_without_frames_and_their_errors(tmp_path):
    # no --frames: an empty RigState bag and the counts
    proc = clutch("import", VECTOR / "logfile.asc", "-o", tmp_path / "a", "--json")
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)
    assert result["frames"] == 20 and result["error_frames"] == 4 and "can_frames" not in result
    # this BLF is stamped in 2047: the frames do not fit a ROS Time
    one_error_line(
        clutch("import", VECTOR / "test_CanMessage.blf", "-o", tmp_path / "b", "--frames"),
        "test_CanMessage.blf", "does not fit a ROS Time",
    )  # fmt: skip
    assert not (tmp_path / "b").exists()
    # truncated ASC (no End TriggerBlock) and garbage BLF
    cut = tmp_path / "cut.asc"
    cut.write_bytes((VECTOR / "logfile.asc").read_bytes()[:400])
    one_error_line(clutch("import", cut, "-o", tmp_path / "c"), "cut.asc", "truncated ASC")
    junk = tmp_path / "junk.blf"
    junk.write_bytes(b"not a blf file" * 20)
    one_error_line(clutch("import", junk, "-o", tmp_path / "d"), "junk.blf", "not a BLF file")


# -- our own rig frames through ASC and BLF ----------------------------------------------------

T0 = 1_700_000_000.0  # log start [s]
N_MS = 300  # frames for 0.3 s


def rig_values(k: int) -> dict:
    """SI values of the rig signals at millisecond ``k`` (quantization-friendly)."""
    return {
        "pressure": (5.0 + 0.1 * k) * 1e5,  # [Pa] 5 bar + 0.1 bar/ms
        "torque": 100.0 + 2.5 * k,  # [N m]
        "input_rpm": 30.0 + 0.01 * k,  # [rpm]
        "output_rpm": 2.0,  # [rpm]
        "lamella": 40.0 + 0.5 * (k // 100),  # [degC] every 100 ms
        "oil": 35.25,
        "current": 1.5,  # [A]
        "ff": [0.5 + 0.01 * i for i in range(8)],  # [V]
        "wheels_rpm": [60.0, 61.0, 62.0, 63.0],
        "request": 250.0,  # [N m]
    }


def rig_frames() -> list[can.Message]:
    db = RigDatabase()
    out = []
    for k in range(N_MS):
        v, t = rig_values(k), T0 + k * 1e-3
        out.append(db.make_message("RigFast", {
            "ActuatingPressure": v["pressure"], "MeasuredTorque": v["torque"],
            "MeasuredTorqueValid": 1, "RigFast_Counter": k % 16}, timestamp=t))
        out.append(db.make_message("RigSpeed", {
            "InputShaftSpeed": v["input_rpm"] * RPM, "OutputShaftSpeed": v["output_rpm"] * RPM,
            "RigSpeed_Counter": k % 16}, timestamp=t))
        if k % 10 == 0:
            out.append(db.make_message("PumpStatus", {
                "PumpSts_State": 2, "PumpSts_ActualPressure": v["pressure"],
                "PumpSts_Current": v["current"], "PumpSts_FltOverCurrent": 0,
                "PumpSts_FltOverTemp": 0, "PumpSts_FltUnderVoltage": 0, "PumpSts_FltSensor": 0,
                "PumpSts_FltReqTimeout": 0, "PumpSts_FltReqChecksum": 0,
                "PumpSts_FltReqCounter": 0}, counter=(k // 10) % 16, timestamp=t))
            out.append(db.make_message("FlexiForceFront", {
                f"FF_Front{i + 1}": v["ff"][i] for i in range(4)}, timestamp=t))
            out.append(db.make_message("FlexiForceRear", {
                f"FF_Rear{i + 1}": v["ff"][4 + i] for i in range(4)}, timestamp=t))
            out.append(db.make_message("WheelSpeeds", {
                name: rpm * RPM for name, rpm in zip(
                    ("WheelSpeedFL", "WheelSpeedFR", "WheelSpeedRL", "WheelSpeedRR"),
                    v["wheels_rpm"])}, timestamp=t))
            out.append(db.make_message("TorqueRequest", {"TorqueRequest": v["request"]},
                                       timestamp=t))
        if k % 100 == 0:
            out.append(db.make_message("RigTemperatures", {
                "LamellaTemperature": v["lamella"], "OilTemperature": v["oil"]}, timestamp=t))
        if k == 150:  # an error frame and an unknown frame in the middle
            out.append(can.Message(timestamp=t, is_error_frame=True))
            out.append(can.Message(timestamp=t, arbitration_id=0x7FF, data=b"\x01\x02"))
    return out  # fmt: skip


@pytest.mark.parametrize("writer", [can.ASCWriter, can.BLFWriter])
def test_rig_frames_written_by_python_can_are_imported_with_their_values(tmp_path, writer):
    suffix = ".asc" if writer is can.ASCWriter else ".blf"
    log = tmp_path / f"rig{suffix}"
    frames = rig_frames()
    w = writer(str(log))
    for frame in frames:
        w.on_message_received(frame)
    w.stop()
    out = tmp_path / "rig"
    proc = clutch("import", log, "-o", out, "--json", "--frames")
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)
    assert result["frames"] == result["can_frames"] == len(frames)
    assert result["error_frames"] == 1 and result["unknown_frames"] == 1
    assert result["decode_errors"] == 0
    # a sample per millisecond of log time (the grid starts at the first frame); a sample
    # holds the frames before its grid time and is stamped with the newest of them
    assert N_MS - 3 <= result["messages"] <= N_MS, result

    rig = read_rig_states(out)
    cols, _, _ = read_columns(out, "/can_frames")
    assert int(cols["is_error"].sum()) == 1 and 0x7FF in cols["id"].tolist()
    origin = cols["stamp_ns"].min()  # first frame (ASC stores times relative to its start)
    k = np.round((rig.stamp_ns - origin) / 1e6).astype(int)
    assert np.allclose(rig.stamp_ns - origin, k * 1e6, atol=1e3)  # stamps are frame times
    assert (np.diff(k) > 0).all() and k[0] <= 2 and k[-1] == N_MS - 1
    assert np.array_equal(rig.bag_time_ns, rig.stamp_ns)
    v = [rig_values(i) for i in k]
    assert np.allclose(rig.actuating_pressure, [x["pressure"] for x in v], atol=100.0)  # 1 mbar
    assert np.allclose(rig.measured_torque, [x["torque"] for x in v], atol=0.05)
    assert rig.has_measured_torque.all()
    assert np.allclose(rig.input_speed, [x["input_rpm"] * RPM for x in v], atol=1e-4)
    assert np.allclose(rig.slip_speed, [(x["input_rpm"] - 2.0) * RPM for x in v], atol=1e-4)
    assert np.allclose(rig.lamella_temperature, [x["lamella"] for x in v], atol=0.005)
    assert np.allclose(rig.oil_temperature, 35.25, atol=0.005)
    assert np.allclose(rig.pump_current, 1.5, atol=1e-3)
    assert np.allclose(rig.ff_voltages, np.array([x["ff"] for x in v]), atol=1e-4)
    assert np.allclose(rig.wheel_speeds, np.array([x["wheels_rpm"] for x in v]) * RPM, atol=0.01)
    assert np.allclose(rig.torque_request, 250.0, atol=0.05)
    assert (rig.stale_mask == 0).all()


def test_progress_bar_on_a_terminal_ends_its_line_before_an_error(tmp_path, capsys, monkeypatch):
    from clutch_ros.cli import main as clutch_main

    rows = [f"{i * 0.001:.3f},{i % 40}.5,40.0,10.0" for i in range(40_000)]
    rows[-1] = "39.999,12.5x,40.0,10.0"  # a bad value on the last line
    big = tmp_path / "big.csv"
    big.write_text("time_s,pressure_bar,lamella_temp_c,diff_speed_rpm\n" + "\n".join(rows))
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert clutch_main(["import", str(big), "-o", str(tmp_path / "big")]) == 2
    err = capsys.readouterr().err
    bar, error = err.rstrip("\n").rsplit("\n", 1)
    assert "big.csv [" in bar and "%" in bar  # the bar was drawn ...
    assert error.startswith("clutch import: error: ")  # ... and the error has its own line
    assert "line 40001: cannot parse '12.5x'" in error
    assert not (tmp_path / "big").exists()
