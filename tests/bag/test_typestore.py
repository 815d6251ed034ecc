"""Typestore from msg_defs/msg/*.msg: registration, CDR round trips, bytes equal to rclpy's."""

import json
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

from clutch_ros.bag.errors import MessageFieldError, UnknownTypeError
from clutch_ros.bag.typestore import (
    BASE_STORE,
    CAN_FRAME_TYPE,
    CLUTCH_TYPES,
    RIG_STATE_TYPE,
    can_frame_msg,
    clutch_typestore,
    find_msg_dir,
    make_msg,
    ns_to_stamp,
    rig_state_msg,
    stamp_to_ns,
)

from .conftest import STAMP_NS, cdr, reference_fields, reference_msg

REPO = Path(__file__).resolve().parents[2]
MSG_FILES = sorted((REPO / "msg_defs" / "msg").glob("*.msg"))


def test_every_msg_file_is_registered_from_the_files(store):
    assert find_msg_dir() == (REPO / "msg_defs" / "msg").resolve()
    assert len(MSG_FILES) == 5
    names = {f"clutch_msgs/msg/{p.stem}" for p in MSG_FILES}
    assert names == set(CLUTCH_TYPES)
    for path in MSG_FILES:
        typename = f"clutch_msgs/msg/{path.stem}"
        fields = [name for name, _ in store.fielddefs[typename][1]]
        declared = [
            line.split("#")[0].split()[1]
            for line in path.read_text().splitlines()
            if line.split("#")[0].strip()
        ]
        assert fields == declared, typename
    # the base distribution provides the standard types the package uses
    assert BASE_STORE.name in {"ROS2_KILTED", "ROS2_JAZZY"}
    for std in ("std_msgs/msg/Header", "rosgraph_msgs/msg/Clock"):
        assert std in store.types
    assert "diagnostic_msgs/msg/DiagnosticArray" in store.types


def test_typestore_is_cached_and_follows_an_explicit_dir(tmp_path):
    assert clutch_typestore() is clutch_typestore()
    (tmp_path / "RigState.msg").write_text("std_msgs/Header header\nfloat64 only_field\n")
    other = clutch_typestore(tmp_path)
    assert other is not clutch_typestore()
    assert [n for n, _ in other.fielddefs[RIG_STATE_TYPE][1]] == ["header", "only_field"]


@pytest.mark.parametrize("typename", CLUTCH_TYPES)
def test_cdr_round_trip_of_each_type(store, typename):
    msg = reference_msg(typename)
    raw = store.serialize_cdr(msg, typename)
    back = store.deserialize_cdr(raw, typename)
    assert bytes(store.serialize_cdr(back, typename)) == bytes(raw)
    for name, value in reference_fields(typename).items():
        got = getattr(back, name)
        if isinstance(value, list):
            assert np.array_equal(got, value), name
        else:
            assert got == value, name
    assert stamp_to_ns(back.header.stamp) == STAMP_NS
    assert back.header.frame_id == "clutch"


def _padding_mask(store, msg, typename) -> np.ndarray:
    """Mark where rosbags' CDR output is alignment padding (bytes it never writes)."""
    msgdef = store.get_msgdef(typename)
    size = 4 + msgdef.getsize_cdr(0, msg, store)
    probe = memoryview(bytearray(b"\xff" * size))
    struct.pack_into("BBBB", probe, 0, 0, 1, 0, 0)
    assert msgdef.serialize_cdr_le(probe[4:], 0, msg, store) + 4 == size
    zero = np.frombuffer(cdr(msg, typename), dtype=np.uint8)
    return np.frombuffer(bytes(probe), dtype=np.uint8) != zero


def _rclpy_msg(typename: str, fields: dict, frame_id: str):
    import clutch_msgs.msg

    msg = getattr(clutch_msgs.msg, typename.rsplit("/", 1)[-1])()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(STAMP_NS, 1_000_000_000)
    msg.header.frame_id = frame_id
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


@pytest.mark.parametrize("frame_id", ["clutch", "", "abc"])
@pytest.mark.parametrize("typename", CLUTCH_TYPES)
def test_cdr_bytes_equal_rclpy_serialize_message(store, typename, frame_id):
    """Rosbags and rclpy (rosidl/Fast CDR typesupport) produce the same CDR for each type.

    Fast CDR leaves alignment padding uninitialised (it differs from call to call), so the
    padding bytes are excluded from the comparison; rosbags writes them as zeros.
    """
    from rclpy.serialization import deserialize_message, serialize_message

    fields = reference_fields(typename, seed=3)
    ours = reference_msg(typename, seed=3, frame_id=frame_id)
    ours.header.stamp = ns_to_stamp(STAMP_NS)
    ros_msg = _rclpy_msg(typename, fields, frame_id)
    theirs = np.frombuffer(bytes(serialize_message(ros_msg)), dtype=np.uint8)
    mine = np.frombuffer(cdr(ours, typename), dtype=np.uint8)
    assert len(mine) == len(theirs)
    pad = _padding_mask(store, ours, typename)
    assert not pad[:4].any()
    assert np.array_equal(mine[~pad], theirs[~pad]), typename
    assert not mine[pad].any(), "rosbags padding must be zero"
    # and both ways through each other's deserializer
    assert deserialize_message(mine.tobytes(), type(ros_msg)) == ros_msg
    back = store.deserialize_cdr(theirs.tobytes(), typename)
    assert cdr(back, typename) == mine.tobytes()


@pytest.mark.parametrize("typename", CLUTCH_TYPES)
def test_type_hash_equals_rosidl_generated_hash(store, typename):
    """The RIHS01 hash rosbags records in bags equals the one rosidl generated for clutch_msgs."""
    stem = typename.rsplit("/", 1)[-1]
    found = [p / f"{stem}.json" for p in (Path(sys.prefix) / "share" / "clutch_msgs" / "msg",)]
    found = [p for p in found if p.exists()]
    if not found:
        pytest.skip("clutch_msgs not installed in this environment")
    described = json.loads(found[0].read_text())
    hashes = {h["type_name"]: h["hash_string"] for h in described["type_hashes"]}
    assert store.hash_rihs01(typename) == hashes[typename]


def test_builders_fill_defaults_and_convert_plain_values():
    msg = rig_state_msg(STAMP_NS, actuating_pressure=3, ff_voltages=(1, 2), frame_id="rig")
    assert stamp_to_ns(msg.header.stamp) == STAMP_NS and msg.header.frame_id == "rig"
    assert msg.actuating_pressure == 3.0 and isinstance(msg.actuating_pressure, float)
    assert msg.ff_voltages.dtype == np.float64 and list(msg.ff_voltages) == [1.0, 2.0]
    assert msg.wheel_speeds.shape == (0,) and msg.has_measured_torque is False
    frame = can_frame_msg(5, 0x123, b"\x01\x02")
    assert list(frame.data) == [1, 2, 0, 0, 0, 0, 0, 0] and frame.dlc == 2
    assert cdr(frame, CAN_FRAME_TYPE)  # serializes


def test_builders_reject_unknown_fields_and_bad_values():
    with pytest.raises(MessageFieldError, match="no field.*pressure_bar"):
        rig_state_msg(0, pressure_bar=1.0)
    with pytest.raises(MessageFieldError, match="actuating_pressure"):
        rig_state_msg(0, actuating_pressure="high")
    with pytest.raises(MessageFieldError, match="fixed array of 8"):
        can_frame_msg(0, 1, bytes(9))
    with pytest.raises(UnknownTypeError, match="acme_msgs/msg/Nope"):
        make_msg("acme_msgs/msg/Nope")
    with pytest.raises(MessageFieldError, match="int32"):
        ns_to_stamp(2**31 * 1_000_000_000)


def test_stamp_conversions_are_exact():
    for ns in (0, 1, 999_999_999, 1_000_000_000, STAMP_NS, -1_500_000_000):
        assert stamp_to_ns(ns_to_stamp(ns)) == ns
    stamp = ns_to_stamp(-1_500_000_000)
    assert (stamp.sec, stamp.nanosec) == (-2, 500_000_000)


def test_msg_dir_falls_back_to_an_installed_share(tmp_path, monkeypatch):
    import clutch_ros.bag.typestore as ts

    share = tmp_path / "prefix" / "share" / "clutch_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "TorqueRequest.msg").write_text("std_msgs/Header header\nfloat64 torque\n")
    monkeypatch.setattr(ts, "_source_msg_dir", lambda: tmp_path / "no_checkout")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    assert ts.find_msg_dir() == share.resolve()
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "elsewhere"))
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "prefix"))  # never searched (a rig PC's /usr)
    with pytest.raises(ts.BagError, match="no clutch_msgs .msg files found"):
        ts.find_msg_dir()
