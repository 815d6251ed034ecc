"""MDF4 (written by asammdf here) and a renamed-column CSV import to the reference CSV's values.

The reference is ``tests/data/csv/rig_run.csv`` through the standard CSV import. The same
samples are written (1) as an MDF4 file with asammdf, under the names and units a rig's
CANape configuration might use (bar -> kPa for the pressure, rpm, degC, K for the oil, N m,
mV for FlexiForce), and (2) as a CSV with other column names; both import through a channel
map and give the same RigState values (to float rounding of the unit conversions).
"""

import csv
import math

import numpy as np
import pytest
import yaml

from clutch_ros.bag.channel_map import MapError, load_map
from clutch_ros.bag.csv_import import import_csv
from clutch_ros.bag.mapped_import import import_mapped
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.cli.main import main as clutch
from tests.conftest import REPO

REFERENCE = REPO / "tests" / "data" / "csv" / "rig_run.csv"
RPM = 2 * math.pi / 60
#: foreign name, unit, factor from the reference CSV unit, offset
FOREIGN = {
    "pressure_bar": ("P_Kupplung", "kPa", 100.0, 0.0),
    "lamella_temp_c": ("T_Lamelle", "degC", 1.0, 0.0),
    "oil_temp_c": ("T_Oel", "K", 1.0, 273.15),
    "diff_speed_rpm": ("n_diff", "rpm", 1.0, 0.0),
    "input_speed_rpm": ("n_ein", "rpm", 1.0, 0.0),
    "output_speed_rpm": ("n_aus", "rpm", 1.0, 0.0),
    "torque_nm": ("M_Welle", "N m", 1.0, 0.0),
    "torque_request_nm": ("M_Soll", "N m", 1.0, 0.0),
    **{f"ff_{s}_{i}_v": (f"FF_{s[0].upper()}{i}", "mV", 1000.0, 0.0)
       for s in ("front", "rear") for i in range(1, 5)},
}
FIELD_OF = {"pressure_bar": "actuating_pressure", "lamella_temp_c": "lamella_temperature",
            "oil_temp_c": "oil_temperature", "diff_speed_rpm": "slip_speed",
            "input_speed_rpm": "input_speed", "output_speed_rpm": "output_speed",
            "torque_nm": "measured_torque", "torque_request_nm": "torque_request"}
COMPARED = ["actuating_pressure", "lamella_temperature", "oil_temperature", "slip_speed",
            "input_speed", "output_speed", "measured_torque", "torque_request"]


def _reference():
    with REFERENCE.open() as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) if r[k].strip() else np.nan for r in rows]) for k in rows[0]}


def _map(tmp_path, time_entry):
    fields = {FIELD_OF[k]: {"channel": FOREIGN[k][0], "unit": FOREIGN[k][1]}
              for k in FIELD_OF}
    fields["ff_voltages"] = {"channels": [FOREIGN[f"ff_{s}_{i}_v"][0] for s in ("front", "rear")
                                          for i in range(1, 5)], "unit": "mV"}
    tree = {"fields": fields}
    if time_entry:
        tree["time"] = time_entry
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump(tree))
    return path


def _check_same(bag, ref_bag):
    got, ref = read_rig_states(bag), read_rig_states(ref_bag)
    np.testing.assert_array_equal(got.stamp_ns, ref.stamp_ns)
    for name in COMPARED:
        # rtol 1e-12: only the float rounding of the unit conversions (x100 / 1e5, +273.15)
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-12,
                                   atol=1e-9, err_msg=name)
    np.testing.assert_array_equal(got.has_measured_torque, ref.has_measured_torque)
    assert not ref.has_measured_torque.all() and ref.has_measured_torque.any()  # both kinds
    np.testing.assert_allclose(got.columns["ff_voltages"], ref.columns["ff_voltages"],
                               rtol=1e-12, atol=1e-12)


@pytest.fixture
def reference_bag(tmp_path):
    import_csv(REFERENCE, tmp_path / "ref")
    return tmp_path / "ref"


def test_mdf4_written_by_asammdf_imports_to_the_reference_values(tmp_path, reference_bag):
    from asammdf import MDF, Signal

    ref = _reference()
    t = ref["time_s"]
    mdf = MDF(version="4.10")
    mdf.append([Signal(samples=ref[k] * f + o, timestamps=t, name=name, unit=unit)
                for k, (name, unit, f, o) in FOREIGN.items()])
    path = tmp_path / "run.mf4"
    mdf.save(str(path), overwrite=True)
    mdf.close()
    cmap = _map(tmp_path, None)
    assert clutch(["import", str(path), "--map", str(cmap), "-o", str(tmp_path / "mdf")]) == 0
    _check_same(tmp_path / "mdf", reference_bag)


def test_csv_with_other_column_names_imports_through_the_same_map(tmp_path, reference_bag):
    ref = _reference()
    path = tmp_path / "foreign.csv"
    names = ["Zeit_ms", *(FOREIGN[k][0] for k in FOREIGN)]
    with path.open("w", newline="") as fh:
        w = csv.writer(fh, delimiter=";")
        w.writerow(names)
        for i in range(len(ref["time_s"])):
            row = [ref["time_s"][i] * 1000.0] + [ref[k][i] * f + o
                                                 for k, (_, _, f, o) in FOREIGN.items()]
            w.writerow([repr(float(v)).replace(".", ",") for v in row])
    cmap = load_map(_map(tmp_path, {"channel": "Zeit_ms", "unit": "ms"}))
    n, _ = import_mapped(path, tmp_path / "csv", cmap)
    assert n == len(ref["time_s"])
    _check_same(tmp_path / "csv", reference_bag)


def test_bad_maps_and_missing_channels_are_clear_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    cases = [({"fields": {"actuating_pressure": {"channel": "P", "unit": "furlong"}}},
              "unit 'furlong' is not a pressure unit"),
             ({"fields": {"pressure": {"channel": "P", "unit": "bar"}}},
              "'pressure' is not a RigState field"),
             ({"fields": {"actuating_pressure": {"channel": "P", "unit": "bar"}}},
              "required field(s) lamella_temperature, slip_speed not mapped")]
    for tree, text in cases:
        bad.write_text(yaml.safe_dump(tree))
        with pytest.raises(MapError) as err:
            load_map(bad)
        assert text in str(err.value)
    cmap = load_map(_map(tmp_path, {"channel": "time_s", "unit": "s"}))
    with pytest.raises(MapError, match="P_Kupplung.*not in the header"):
        import_mapped(REFERENCE, tmp_path / "x", cmap)
    assert clutch(["import", str(tmp_path / "missing.mf4"), "-o", str(tmp_path / "y")]) == 2
