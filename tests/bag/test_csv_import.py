"""Rig CSV import: SI conversion, layout, every bad-input case with its message."""

import math

import numpy as np
import pytest

from clutch_ros.bag.csv_import import import_csv
from clutch_ros.bag.errors import BagExistsError, CsvError
from clutch_ros.bag.reader import open_bag
from clutch_ros.bag.rig_states import read_rig_states

from .conftest import DATA, np_equal

RPM = 2 * math.pi / 60


def _csv(tmp_path, text, name="gen.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


HEADER = "time_s,pressure_bar,lamella_temp_c,diff_speed_rpm\n"


def test_good_file_converted_to_si(tmp_path):
    out = tmp_path / "run"
    summary = import_csv(DATA / "rig_run.csv", out)
    assert summary.messages == 5 and summary.bag == out and summary.topic == "/rig_state"
    assert summary.start_ns == 0 and summary.end_ns == 4_000_000
    assert summary.duration_s == pytest.approx(0.004)
    assert summary.ignored_columns == [] and summary.columns["pressure_bar"] == (
        "actuating_pressure"
    )
    a = read_rig_states(out)
    assert np_equal(a.stamp_ns, [0, 1_000_000, 2_000_000, 3_000_000, 4_000_000])
    assert np_equal(a.bag_time_ns, a.stamp_ns)
    assert np.allclose(a.actuating_pressure, [0.0, 1.5e5, 10e5, 40e5, 20e5])
    assert np.allclose(a.lamella_temperature, [35.0, 35.1, 35.2, 36.0, 36.5])
    assert np.allclose(a.slip_speed, np.array([10, 10, 30, 50, -30]) * RPM)
    assert np.allclose(a.input_speed, np.array([10, 10, 30, 50, -30]) * RPM)
    assert np.allclose(a.output_speed, 0.0) and np.allclose(a.oil_temperature[-1], 30.2)
    assert np_equal(a.measured_torque, [0.0, 12.5, np.nan, 1440.0, -700.25])
    assert a.has_measured_torque.tolist() == [True, True, False, True, True]
    assert np.allclose(a.torque_request, [0, 20, 100, 1440, 700])
    assert np.isnan(a.pump_current).all()  # absent column -> NaN, not 0
    assert a.ff_voltages.shape == (5, 8)  # front 1-4 then rear 1-4
    assert np.allclose(a.ff_voltages[3], [1.00, 1.01, 1.02, 1.03, 0.90, 0.91, 0.92, 0.93])
    assert np.allclose(a.wheel_speeds[0], np.array([60, 61, 62, 63]) * RPM)
    with open_bag(out) as bag:
        assert bag.custom_data["clutch_ros.source"] == "rig_run.csv"
        assert bag.custom_data["clutch_ros.ff_voltages"].startswith("ff_front_1_v,ff_front_2_v")
        ((_, _, first), *_) = list(bag.messages())
    assert first.header.frame_id == "rig"


def test_semicolon_decimal_comma_bom_comments_blank_lines(tmp_path):
    summary = import_csv(DATA / "rig_run_semicolon.csv", tmp_path / "sc", storage="sqlite3")
    assert summary.messages == 5 and summary.storage == "sqlite3"
    assert summary.ignored_columns == ["comment"]
    a = read_rig_states(tmp_path / "sc")
    ref = read_rig_states(import_csv(DATA / "rig_run.csv", tmp_path / "ref").bag)
    for name in ("stamp_ns", "actuating_pressure", "lamella_temperature", "slip_speed"):
        assert np.allclose(getattr(a, name), getattr(ref, name)), name
    assert np_equal(a.measured_torque, ref.measured_torque)
    assert a.ff_voltages.shape == (5, 0) and a.wheel_speeds.shape == (5, 0)
    assert np.isnan(a.oil_temperature).all()


def test_other_units_are_converted(tmp_path):
    path = _csv(
        tmp_path,
        "Time_ms,PRESSURE_KPA,lamella_temp_k,diff_speed_rad_s,torque_knm,ff_rear_2_mv\n"
        "0,100,308.15,1.5,0.5,250\n"
        "2.5,4000,423.15,3.0,1.44,500\n",
    )
    a = read_rig_states(import_csv(path, tmp_path / "u").bag)
    assert np_equal(a.stamp_ns, [0, 2_500_000])
    assert np.allclose(a.actuating_pressure, [1e5, 40e5])
    assert np.allclose(a.lamella_temperature, [35.0, 150.0])
    assert np.allclose(a.slip_speed, [1.5, 3.0]) and np.allclose(a.measured_torque, [500, 1440])
    assert np.allclose(a.ff_voltages[:, 0], [0.25, 0.5])


def test_time_offset_and_progress_on_a_large_file(tmp_path):
    rows = 20_000
    t = np.arange(rows) / 1000.0
    body = "".join(f"{x:.3f},{x % 40:.2f},{35 + x:.2f},30\n" for x in t)
    path = _csv(tmp_path, HEADER + body)
    seen = []
    summary = import_csv(path, tmp_path / "big", progress=seen.append, time_offset_ns=10**18)
    assert summary.messages == rows and summary.start_ns == 10**18
    assert seen == sorted(seen) and seen[-1] == 1.0 and 50 <= len(seen) <= 102
    a = read_rig_states(tmp_path / "big")
    assert len(a) == rows and a.stamp_ns[-1] == 10**18 + (rows - 1) * 1_000_000


def _fails(tmp_path, src, match):
    out = tmp_path / "out"
    with pytest.raises(CsvError, match=match) as err:
        import_csv(src, out)
    assert not out.exists(), "a failed import must not leave a partial bag"
    assert src.name in str(err.value)
    return err.value


def test_missing_required_column(tmp_path):
    err = _fails(
        tmp_path, DATA / "missing_lamella_temp.csv", "missing required column 'lamella_temp_c'"
    )
    assert err.column == "lamella_temp_c" and err.line == 1


def test_non_monotonic_time_names_the_line(tmp_path):
    err = _fails(
        tmp_path,
        DATA / "time_goes_back.csv",
        r"time_goes_back\.csv: line 5: time does not increase \(0\.0015 s after 0\.002 s\)",
    )
    assert err.line == 5 and err.column == "time_s"
    _fails(tmp_path, _csv(tmp_path, HEADER + "0,1,35,10\n0,1,35,10\n"), "line 3: time does not")


def test_unparseable_value_names_line_and_column(tmp_path):
    err = _fails(
        tmp_path,
        DATA / "bad_value.csv",
        r"bad_value\.csv: line 4: cannot parse '12\.5x' as a number in column 'pressure_bar'",
    )
    assert (err.line, err.column) == (4, "pressure_bar")


def test_empty_file_and_header_only(tmp_path):
    _fails(tmp_path, DATA / "empty.csv", r"empty\.csv: empty file: no header line")
    _fails(tmp_path, _csv(tmp_path, "\n# only a comment\n\n", "blank.csv"), "empty file")
    _fails(tmp_path, _csv(tmp_path, HEADER), "line 1: no data rows after the header")


@pytest.mark.parametrize(
    "rows, match",
    [
        ("0,1,35,10\n0.001,1,,10\n", "line 3: empty value"),
        ("0,1,35,10\n0.001,1,35\n", "line 3: expected 4 values, found 3"),
        ("0,1,35,10,99\n", "line 2: expected 4 values, found 5"),
        ("0,1,35,nan\n", "line 2: 'nan' is not a finite number in column 'diff_speed_rpm'"),
        ("inf,1,35,10\n", "line 2: 'inf' is not a finite number in column 'time_s'"),
        ('0,1,35,"10\n', "line 2: malformed CSV"),
        ("-0.5,1,35,10\n", "line 2: time -0.5 s gives a stamp before 1970"),
    ],
)
def test_bad_rows(tmp_path, rows, match):
    _fails(tmp_path, _csv(tmp_path, HEADER + rows), match)


def test_late_error_removes_the_partial_bag(tmp_path):
    body = "".join(f"{i / 1000:.3f},1,35,10\n" for i in range(3000)) + "3.5,x,35,10\n"
    err = _fails(tmp_path, _csv(tmp_path, HEADER + body), "line 3002: cannot parse 'x'")
    assert err.column == "pressure_bar"


def test_duplicate_quantity_and_existing_output(tmp_path):
    _fails(
        tmp_path,
        _csv(
            tmp_path, "time_s,pressure_bar,pressure_pa,lamella_temp_c,diff_speed_rpm\n0,1,1,1,1\n"
        ),
        "columns 'pressure_bar' and 'pressure_pa' give the same quantity",
    )
    out = tmp_path / "exists"
    out.mkdir()
    with pytest.raises(BagExistsError, match="exists"):
        import_csv(DATA / "rig_run.csv", out)
    assert list(out.iterdir()) == []
    with pytest.raises(CsvError, match="nope.csv: cannot open"):
        import_csv(tmp_path / "nope.csv", tmp_path / "x")
