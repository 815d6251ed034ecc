"""The interface tables (clutch_ros.interfaces): stamps, units, ClutchEstimate fields, topics."""

import ast
import math
import re
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from clutch_ros import interfaces as ifc
from tests.conftest import REPO

NS = ifc.NS_PER_S


# -- stamps ------------------------------------------------------------------------------
@given(st.integers(min_value=-(2**62), max_value=2**62))
def test_ns_and_stamp_round_trip_exactly(ns):
    sec, nanosec = ifc.ns_to_stamp(ns)
    assert 0 <= nanosec < NS and ifc.stamp_to_ns(sec, nanosec) == ns


@given(st.integers(min_value=-(10**15), max_value=10**15))
def test_ns_to_seconds_and_back_is_exact_within_eleven_days(ns):
    # ns / 1e9 is correctly rounded; * 1e9 adds one more rounding: the error stays below
    # 0.5 ns while |ns| * 2**-52 < 0.5, i.e. |ns| < 2.2e15 ns (25 days)
    assert ifc.s_to_ns(ifc.ns_to_s(ns)) == ns


@given(st.integers(min_value=0, max_value=2**31 - 1), st.integers(min_value=0, max_value=NS - 1))
def test_stamp_to_seconds_and_back_within_the_float_resolution(sec, nanosec):
    seconds = ifc.stamp_to_s(sec, nanosec)
    assert seconds == sec + nanosec * 1e-9  # the node's formula, bit for bit
    back = ifc.stamp_to_ns(*ifc.s_to_stamp(seconds))
    # a float of seconds since the epoch resolves 2**-22 s (0.24 us) at 2**31 s
    assert abs(back - ifc.stamp_to_ns(sec, nanosec)) <= max(1, sec * 2**-52 * NS)


def test_stamp_edge_cases():
    assert ifc.ns_to_stamp(-1) == (-1, NS - 1)  # negative: floor, nanosec stays positive
    assert ifc.ns_to_stamp(NS) == (1, 0)
    assert ifc.s_to_stamp(1.9999999999) == (2, 0)  # rounding carries into sec, never 1e9 ns
    assert ifc.s_to_stamp(0.5e-9) == (0, 0) and ifc.s_to_stamp(1.5e-9) == (0, 2)  # ties even
    for bad in (-1e-9, -5.0, math.nan, math.inf, -math.inf):
        assert ifc.s_to_stamp(bad) == (0, 0)  # a ROS time is never below zero
    with pytest.raises(ValueError):
        ifc.s_to_ns(math.nan)
    assert ifc.s_to_ns(-1.5) == -1_500_000_000  # plain durations may be negative
    assert ifc.ns_to_s(1) == 1e-9 and ifc.stamp_to_ns(1, 5) == 1_000_000_005


def test_message_stamp_helpers_use_the_table():
    rclpy_stamps = pytest.importorskip("clutch_ros.nodes.stamps")
    stamp = rclpy_stamps.sec_to_stamp(1_700_000_000.123456789)
    assert (stamp.sec, stamp.nanosec) == ifc.s_to_stamp(1_700_000_000.123456789)
    assert rclpy_stamps.stamp_to_sec(stamp) == ifc.stamp_to_s(stamp.sec, stamp.nanosec)


# -- units -------------------------------------------------------------------------------
def test_unit_factors():
    units = ifc.unit_table()
    si = {name: (u.scale, u.offset) for name, u in units.items()}
    assert si["bar"] == (1e5, 0.0) and si["mbar"] == (100.0, 0.0) and si["kPa"] == (1e3, 0.0)
    assert si["psi"][0] == pytest.approx(4.4482216152605 / 0.0254**2, rel=1e-15)
    assert si["rpm"][0] == si["1/min"][0] == 2 * math.pi / 60
    assert si["K"] == (1.0, -273.15) and si["°C"] == si["C"] == si["degC"] == (1.0, 0.0)
    assert si["kNm"] == si["kN m"] == (1e3, 0.0) and si["Nm"] == si["N m"] == (1.0, 0.0)
    assert si["ms"] == (1e-3, 0.0) and si["mA"] == (1e-3, 0.0) and si["mV"] == (1e-3, 0.0)
    for quantity, si_unit in ifc.SI_UNITS.items():  # each SI unit converts to itself
        unit = ifc.unit_table(quantity)[si_unit]
        assert (unit.scale, unit.offset) == (1.0, 0.0), quantity
    assert ifc.fold_unit("rad/s") == "rad_s" and ifc.fold_unit("kN m") == "knm"
    assert ifc.fold_unit("°C") == "degc"


def test_importers_derive_their_units_from_the_table():
    from clutch_ros.bag import channel_map, csv_import
    from clutch_ros.canbus import units

    for quantity, table in channel_map.UNITS.items():
        assert table == {k: (u.scale, u.offset) for k, u in ifc.unit_table(quantity).items()}
    assert csv_import.UNITS["pressure"]["kpa"] == (1e3, 0.0)
    assert csv_import.UNITS["time"]["ms"] == (1e6, 0.0)  # the CSV time base is ns
    assert csv_import.UNITS["temperature"]["k"] == (1.0, -273.15)
    assert csv_import.UNITS["speed"]["rad_s"] == (1.0, 0.0)
    assert units.UNIT_TO_SI["bar"] == ("Pa", 1e5) and units.UNIT_TO_SI[""] == ("", 1.0)
    assert "K" not in units.UNIT_TO_SI and "ms" not in units.UNIT_TO_SI  # scale-only, no time


# -- ClutchEstimate fields ---------------------------------------------------------------
def _msg_fields(name: str) -> list[tuple[str, str, str]]:
    """(type, name, unit) of each field of ``msg_defs/msg/<name>.msg`` (header aside)."""
    out = []
    for line in (REPO / "msg_defs" / "msg" / f"{name}.msg").read_text().splitlines():
        match = re.match(r"^(\S+)\s+(\w+)\s*(?:#\s*(?:\[([^\]]*)\])?)?", line)
        if match and not line.startswith("#") and match.group(2) != "header":
            out.append((match.group(1), match.group(2), match.group(3) or ""))
    return out


def test_estimate_field_table_is_the_message_definition():
    fields = _msg_fields("ClutchEstimate")
    assert [f.name for f in ifc.ESTIMATE_FIELDS] == [name for _, name, _ in fields]
    for spec, (typ, name, unit) in zip(ifc.ESTIMATE_FIELDS, fields):
        assert spec.kind == typ, name
        assert spec.unit == unit, (name, unit)  # the .msg comment states it in brackets


def test_estimate_fields_come_from_model_outputs():
    from clutch_ros.model.adaptation import AdaptationStatus
    from clutch_ros.model.batch import EstimateBatch
    from clutch_ros.model.estimator import Estimate

    for spec in ifc.ESTIMATE_FIELDS:
        if spec.source == "uncertainty":  # the error model's output, set by node and replay
            assert spec.name == "modelled_torque_std", spec
            continue
        owners = (Estimate, EstimateBatch) if spec.source == "estimate" else (AdaptationStatus,)
        for owner in owners:
            assert spec.attr in owner.__dataclass_fields__, (spec.name, owner.__name__)
    assert "spline_correction" in ifc.estimate_fields("estimate", ("float64",))


# -- topics ------------------------------------------------------------------------------
def test_topics_are_unique_typed_and_reliable():
    names = [t.name for t in ifc.TOPICS]
    assert len(set(names)) == len(names) == 7
    msgs = {p.stem for p in (REPO / "msg_defs" / "msg").glob("*.msg")}
    for t in ifc.TOPICS:
        pkg, kind, typ = t.typename.split("/")
        assert kind == "msg" and (pkg != "clutch_msgs" or typ in msgs), t.typename
        assert t.publisher.reliability == ifc.RELIABLE, t.name  # REP 2003: publishers reliable
        assert ifc.topic(t.name) is ifc.topic(t.absolute) is t
    assert ifc.RIG_STATE.publisher == ifc.reliable(50)
    assert ifc.RIG_STATE.subscriber == ifc.SENSOR_DATA
    assert ifc.topic("/clock") is None


def test_rclpy_profiles_from_the_table():
    qos = pytest.importorskip("clutch_ros.nodes.qos")
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    assert qos.sensor_qos() == qos_profile_sensor_data
    assert qos.reliable_qos(50) == QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    assert qos.publisher_qos("rig_state") == qos.reliable_qos(50)
    assert qos.subscriber_qos("/rig_state", depth=200) == QoSProfile(
        depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
    for t in ifc.TOPICS:
        assert qos.spec_of(qos.profile(t.publisher)) == t.publisher


# -- layer ---------------------------------------------------------------------------------
def test_interfaces_imports_only_the_standard_library():
    tree = ast.parse((REPO / "clutch_ros" / "interfaces.py").read_text())
    modules = {alias.name.split(".")[0] for node in ast.walk(tree)
               if isinstance(node, ast.Import) for alias in node.names}
    modules |= {node.module.split(".")[0] for node in ast.walk(tree)
                if isinstance(node, ast.ImportFrom) and node.module}
    assert modules and modules <= set(sys.stdlib_module_names) | {"__future__"}, modules
