"""Column streams: template serialization equals rosbags', zstd chunks, simulated runs."""

import numpy as np
import pytest

from clutch_ros.bag.arrays import TemplateSerializer, read_columns, write_columns
from clutch_ros.bag.errors import MessageFieldError
from clutch_ros.bag.reader import open_bag
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.bag.typestore import CLUTCH_ESTIMATE_TYPE, RIG_STATE_TYPE, make_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.errors import ConfigError
from clutch_ros.offline.rig_runs import START_NS, simulate_run, write_run
from clutch_ros.rig.scenario import table4_run

from .conftest import STAMP_NS


def test_template_bytes_equal_rosbags_serialization(store):
    rng = np.random.default_rng(1)
    n = 40
    cols = {
        "modelled_torque": rng.normal(size=n) * 1e3,
        "torque_accuracy": np.where(rng.random(n) < 0.3, np.nan, rng.random(n)),
        "lamella_normal_force": rng.normal(size=(n, 13)),
        "spline_friction_force": rng.normal(size=(n, 13)),
        "overshoot": rng.random(n) < 0.5,
        "pressure_difference": -rng.random(n) * 1e5,
    }
    stamps = STAMP_NS + np.arange(n) * 1_234_567
    ser = TemplateSerializer(CLUTCH_ESTIMATE_TYPE, frame_id="rig1", spline_law="coulomb",
                             lamella_normal_force=np.zeros(13),
                             spline_friction_force=np.zeros(13))  # fmt: skip
    block = ser.serialize_stamped(stamps, cols)
    assert block.shape == (n, ser.size)
    for i in range(n):
        msg = make_msg(CLUTCH_ESTIMATE_TYPE, int(stamps[i]), frame_id="rig1", spline_law="coulomb",
                       **{k: (v[i] if k != "overshoot" else bool(v[i])) for k, v in cols.items()})
        assert bytes(store.serialize_cdr(msg, CLUTCH_ESTIMATE_TYPE)) == block[i].tobytes(), i


def test_template_rejects_unknown_fields_and_wrong_shapes():
    ser = TemplateSerializer(RIG_STATE_TYPE, ff_voltages=np.zeros(8))
    with pytest.raises(MessageFieldError, match="no numeric field 'pressure'"):
        ser.serialize(2, {"pressure": [1.0, 2.0]})
    with pytest.raises(MessageFieldError, match="do not fit 2 messages of 8"):
        ser.serialize(2, {"ff_voltages": np.zeros((2, 4))})
    with pytest.raises(MessageFieldError, match="not numbers"):
        ser.serialize(1, {"actuating_pressure": ["x"]})
    assert ser.serialize(3, {"actuating_pressure": 5.0}).shape == (3, ser.size)  # broadcast


@pytest.mark.parametrize(("storage", "compression"), [("mcap", "zstd"), ("sqlite3", "none")])
def test_write_columns_read_columns_round_trip(tmp_path, storage, compression):
    n = 3000
    stamps = STAMP_NS + np.arange(n) * 1_000_000
    cols = {"actuating_pressure": np.linspace(0, 4e6, n), "slip_speed": np.full(n, 1.047),
            "has_measured_torque": np.arange(n) % 3 > 0, "ff_voltages": np.ones((n, 8)),
            "measured_torque": np.sin(np.arange(n))}  # fmt: skip
    path = tmp_path / "cols"
    with BagWriter(path, storage=storage, compression=compression) as writer:
        topic = writer.add_topic("rig_state")
        ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
        write_columns(writer, topic, ser, stamps, cols, bag_ns=stamps + 7)
    for fast in (True, False):
        rig = read_rig_states(path, fast=fast)
        assert np.array_equal(rig.stamp_ns, stamps) and np.array_equal(rig.bag_time_ns, stamps + 7)
        for k, v in cols.items():
            assert np.array_equal(getattr(rig, k), v), k
    back, bag_ns, strings = read_columns(path, "/rig_state")
    assert np.array_equal(back["stamp_ns"], stamps) and strings["header.frame_id"] == "rig"
    with open_bag(path) as bag:
        assert bag.message_count == n


def test_zstd_chunks_are_smaller_and_metadata_stays_plain(tmp_path):
    run = simulate_run(table4_run(1), seed=0, rate_hz=100.0, duration=2.0)
    write_run(tmp_path / "plain", run)
    write_run(tmp_path / "zstd", run, compression="zstd")
    size = {k: sum(f.stat().st_size for f in (tmp_path / k).iterdir()) for k in ("plain", "zstd")}
    assert size["zstd"] < 0.8 * size["plain"], size
    meta = (tmp_path / "zstd" / "metadata.yaml").read_text()
    assert "compression_mode: ''" in meta and "compression_format: ''" in meta
    a, b = read_rig_states(tmp_path / "plain"), read_rig_states(tmp_path / "zstd")
    assert np.array_equal(a.actuating_pressure, b.actuating_pressure)
    with pytest.raises(ConfigError, match="zstd compression needs the mcap storage"):
        BagWriter(tmp_path / "x", storage="sqlite3", compression="zstd")
    with pytest.raises(ConfigError, match="unknown bag compression 'lz5'"):
        BagWriter(tmp_path / "x", compression="lz5")


def test_custom_data_set_while_writing(tmp_path):
    path = tmp_path / "custom"
    writer = BagWriter(path, custom_data={"a": "1"}).open()
    writer.add_topic("rig_state")
    writer.set_custom_data("b", "2")
    writer.close()
    with open_bag(path) as bag:
        assert bag.custom_data == {"a": "1", "b": "2"}
    with pytest.raises(Exception, match="closed"):
        writer.set_custom_data("c", "3")


def test_simulated_run_is_decimated_and_deterministic():
    a = simulate_run(table4_run(2), seed=4, rate_hz=100.0, duration=1.5)
    b = simulate_run(table4_run(2), seed=4, rate_hz=100.0, duration=1.5)
    assert len(a) == 150 and a.stamp_ns[0] == START_NS + 10_000_000
    assert (np.diff(a.stamp_ns) == 10_000_000).all()
    assert all(np.array_equal(a.columns[k], b.columns[k]) for k in a.columns)
    assert a.columns["ff_voltages"].shape == (150, 8) and a.columns["wheel_speeds"].shape[1] == 4
    assert (a.columns["torque_request"] == 0.0).all()  # no request: 0, as the message says
    assert np.allclose(a.columns["lamella_temperature"][:10], 60.0, atol=1.0)  # Table 4 seq 2
    assert a.time[-1] == pytest.approx(1.5)
    c = simulate_run(table4_run(2), seed=5, rate_hz=100.0, duration=1.5)
    assert not np.array_equal(a.columns["measured_torque"], c.columns["measured_torque"])
    with pytest.raises(ConfigError, match="not an integer divisor"):
        simulate_run(table4_run(2), rate_hz=300.0, duration=0.1)
