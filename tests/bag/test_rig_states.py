"""read_rig_states / ColumnDecoder: the numpy fast path equals per-message deserialization."""

import numpy as np
import pytest

from clutch_ros.bag import columns
from clutch_ros.bag.columns import ColumnDecoder, CorruptMessageError, columns_slow
from clutch_ros.bag.errors import BagError
from clutch_ros.bag.reader import open_bag
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.bag.typestore import CLUTCH_ESTIMATE_TYPE, RIG_STATE_TYPE, rig_state_msg
from clutch_ros.bag.writer import BagWriter

from .conftest import STAMP_NS, cdr, np_equal, reference_msg

SCALARS = (
    "actuating_pressure", "lamella_temperature", "oil_temperature", "input_speed",
    "output_speed", "slip_speed", "measured_torque", "has_measured_torque", "torque_request",
    "pump_current", "stale_mask",
)  # fmt: skip


def _varied(i: int):
    """RigStates whose layout varies: frame id length, sequence lengths (incl. empty)."""
    return rig_state_msg(
        STAMP_NS + i * 1_000_000,
        frame_id="x" * (i % 7),
        actuating_pressure=1e5 + i,
        lamella_temperature=35.0 + i / 100,
        slip_speed=-1.0 * i,
        measured_torque=i * 0.5,
        has_measured_torque=bool(i % 3),
        stale_mask=i % 5,
        ff_voltages=np.arange(i % 9) + 0.25,
        wheel_speeds=[] if i % 4 == 0 else [1.0, 2.0, 3.0, 4.0 + i],
        pump_current=i / 10,
    )


def _assert_columns_match_messages(cols, msgs):
    for name in SCALARS:
        assert np_equal(cols[name], [getattr(m, name) for m in msgs]), name
    for name in ("ff_voltages", "wheel_speeds"):
        assert np_equal(cols[f"{name}.len"], [len(getattr(m, name)) for m in msgs])
        for row, m in zip(cols[name], msgs):
            n = len(getattr(m, name))
            assert np_equal(row[:n], getattr(m, name)) and np.isnan(row[n:]).all(), name
    assert np_equal(cols["header.stamp.sec"], [m.header.stamp.sec for m in msgs])
    assert np_equal(cols["header.stamp.nanosec"], [m.header.stamp.nanosec for m in msgs])


def test_column_decoder_matches_rosbags_on_varied_layouts(store):
    msgs = [_varied(i) for i in range(200)]
    raws = [cdr(m, RIG_STATE_TYPE) for m in msgs]
    decoder = ColumnDecoder(store, RIG_STATE_TYPE)
    _assert_columns_match_messages(decoder.decode(raws), msgs)
    _assert_columns_match_messages(columns_slow(store, RIG_STATE_TYPE, raws), msgs)
    same = [cdr(rig_state_msg(i, ff_voltages=[i, 2.0], actuating_pressure=i), RIG_STATE_TYPE)
            for i in range(10)]  # fmt: skip
    cols = decoder.decode(same)  # the uniform (strided) path
    assert np_equal(cols["actuating_pressure"], range(10))
    assert np_equal(cols["ff_voltages"][:, 0], range(10))
    assert decoder.decode([])["actuating_pressure"].shape == (0,)


def test_column_decoder_handles_every_clutch_type(store):
    msgs = [reference_msg(CLUTCH_ESTIMATE_TYPE, seed=i) for i in range(5)]
    cols = ColumnDecoder(store, CLUTCH_ESTIMATE_TYPE).decode(
        [cdr(m, CLUTCH_ESTIMATE_TYPE) for m in msgs])
    assert np_equal(cols["modelled_torque"], [m.modelled_torque for m in msgs])
    assert np_equal(cols["overshoot"], [m.overshoot for m in msgs])


def test_column_decoder_rejects_truncated_and_big_endian(store):
    decoder = ColumnDecoder(store, RIG_STATE_TYPE)
    good = cdr(_varied(5), RIG_STATE_TYPE)
    with pytest.raises(CorruptMessageError, match="message 1: truncated at"):
        decoder.decode([good, good[:-12], good])
    with pytest.raises(CorruptMessageError, match="message 0: not little-endian"):
        decoder.decode([b"\x00\x00\x00\x00" + good[4:]])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_read_rig_states_equals_message_reader(tmp_path, storage):
    path = tmp_path / "rs"
    n = 12_000  # > 1 MiB: several MCAP chunks
    msgs = [_varied(i) for i in range(n)]
    with BagWriter(path, storage=storage) as writer:
        writer.add_topic("rig_state")
        writer.add_topic("clutch_estimate")
        for i, msg in enumerate(msgs):
            writer.write("rig_state", STAMP_NS + i * 1_000_000 + 7, msg)
            if i % 100 == 0:
                writer.write("clutch_estimate", STAMP_NS + i, reference_msg(CLUTCH_ESTIMATE_TYPE))
    for fast in (True, False):
        arrays = read_rig_states(path, fast=fast, batch=5000)
        assert len(arrays) == n and arrays.topic == "/rig_state"
        _assert_columns_match_messages(arrays.columns, msgs)
        assert np_equal(arrays.actuating_pressure, [m.actuating_pressure for m in msgs])
        assert arrays.stamp_ns[0] == STAMP_NS and arrays.time[-1] == pytest.approx((n - 1) * 1e-3)
        assert np_equal(arrays.bag_time_ns - arrays.stamp_ns, np.full(n, 7))
        assert arrays.stamp.dtype == np.float64
    with pytest.raises(AttributeError, match="no field 'nope'"):
        _ = arrays.nope


def test_read_rig_states_orders_by_bag_time_like_rosbags(tmp_path):
    path = tmp_path / "order"
    stamps = [5, 1, 3, 3, 2, 9]
    with BagWriter(path) as writer:
        writer.add_topic("rig_state")
        for k, stamp in enumerate(stamps):
            writer.write("rig_state", stamp, rig_state_msg(stamp, actuating_pressure=k))
    with open_bag(path) as bag:
        expected = [(t, m.actuating_pressure) for _, t, m in bag.messages()]
    assert [t for t, _ in expected] == sorted(stamps)
    for fast in (True, False):
        arrays = read_rig_states(path, fast=fast)
        assert list(zip(arrays.bag_time_ns.tolist(), arrays.actuating_pressure)) == expected


def test_read_rig_states_topic_choice(tmp_path):
    path = tmp_path / "two"
    with BagWriter(path) as writer:
        for topic in ("/rig1/rig_state", "/rig2/rig_state"):
            writer.add_topic(topic, RIG_STATE_TYPE)
            writer.write(topic, 1, rig_state_msg(1, slip_speed=len(topic)))
        writer.add_topic("clutch_estimate")
    with pytest.raises(BagError, match="expected one clutch_msgs/msg/RigState topic"):
        read_rig_states(path)
    assert read_rig_states(path, "/rig2/rig_state").slip_speed.tolist() == [15.0]
    with pytest.raises(BagError, match="not RigState"):
        read_rig_states(path, "clutch_estimate")
    with pytest.raises(BagError, match="/rig3/rig_state not in bag"):
        read_rig_states(path, "/rig3/rig_state")


def test_read_rig_states_of_an_empty_topic(tmp_path):
    path = tmp_path / "empty"
    with BagWriter(path) as writer:
        writer.add_topic("rig_state")
    for fast in (True, False):
        arrays = read_rig_states(path, fast=fast)
        assert len(arrays) == 0 and arrays.actuating_pressure.shape == (0,)


def test_column_sink_grows_and_widens():
    from clutch_ros.bag.rig_states import ColumnSink

    sink = ColumnSink(capacity=2)
    sink.add({"a": np.array([1.0, 2.0]), "s": np.array([[1.0, 2.0], [3.0, 4.0]])})
    sink.add({"a": np.array([3.0]), "s": np.array([[5.0, 6.0, 7.0]])})
    sink.add({"a": np.array([4.0]), "s": np.array([[8.0]])})
    out = sink.result({})
    assert np_equal(out["a"], [1, 2, 3, 4])
    nan = np.nan
    assert np_equal(out["s"], [[1, 2, nan], [3, 4, nan], [5, 6, 7], [8, nan, nan]])
    assert ColumnSink(5).result({"x": np.zeros(0)})["x"].shape == (0,)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none", "unchunked"])
def test_mcap_written_by_the_mcap_library_reads_identically(tmp_path, store, compression):
    """Bare .mcap files from another writer: zstd/lz4 chunks with CRCs, or no chunks at all."""
    from mcap.writer import CompressionType, Writer

    file = tmp_path / f"ext_{compression}.mcap"
    msgs = [_varied(i) for i in range(600)]
    msgdef, _ = store.generate_msgdef(RIG_STATE_TYPE, ros_version=2)
    kind = (
        CompressionType.NONE
        if compression in ("none", "unchunked")
        else CompressionType[compression.upper()]
    )
    with file.open("wb") as fh:
        writer = Writer(
            fh, chunk_size=4096, compression=kind, use_chunking=compression != "unchunked"
        )
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(RIG_STATE_TYPE, "ros2msg", msgdef.encode())
        channel = writer.register_channel("/rig_state", "cdr", schema, {})
        for i, msg in enumerate(msgs):
            stamp = STAMP_NS + i * 1_000_000
            writer.add_message(channel, stamp, cdr(msg, RIG_STATE_TYPE), stamp, sequence=i)
        writer.finish()
    for fast in (True, False):
        arrays = read_rig_states(file, fast=fast)
        _assert_columns_match_messages(arrays.columns, msgs)


def test_column_decoder_fixed_layout_shortcut_checks_every_length_field(store, monkeypatch):
    """The fixed-layout shortcut decodes only batches of exactly the learnt layout.

    After a batch of one layout, a batch of equally long messages with another layout (a
    longer frame id, one voltage fewer: same byte count) is walked, not copied at the old
    offsets; a batch of the learnt layout is decoded by the shortcut, identically.
    """

    def batch(msgs):
        raws = [cdr(m, RIG_STATE_TYPE) for m in msgs]
        assert len({len(r) for r in raws}) == 1
        buf = np.frombuffer(b"".join(raws) + bytes(8), dtype=np.uint8)
        lengths = np.full(len(raws), len(raws[0]), dtype=np.int64)
        return buf, np.arange(len(raws), dtype=np.int64) * len(raws[0]), lengths

    def msg(i, frame_id, volts):
        return rig_state_msg(STAMP_NS + i, frame_id=frame_id, actuating_pressure=1e5 + i,
                             slip_speed=-0.5 * i, has_measured_torque=bool(i % 2),
                             ff_voltages=np.arange(volts) + 0.5, wheel_speeds=[1.0, 2.0])

    first = [msg(i, "rig", 8) for i in range(40)]
    other = [msg(i, "rig" + "y" * 8, 7) for i in range(40)]  # 8 bytes more, 8 bytes less
    assert len(cdr(first[0], RIG_STATE_TYPE)) == len(cdr(other[0], RIG_STATE_TYPE))
    walks = []
    run = columns._Walk.run
    monkeypatch.setattr(columns._Walk, "run", lambda self, steps: walks.append(1) or
                        run(self, steps))
    decoder = ColumnDecoder(store, RIG_STATE_TYPE)
    expect = []
    for msgs, walked in ((first, True), (first, False), (other, True), (other, False),
                         (first, True), (other[:1] + first[1:], True), (first, False)):
        before = len(walks)
        cols = decoder.decode_buffer(*batch(msgs))
        _assert_columns_match_messages(cols, msgs)
        expect.append((len(walks) > before) == walked)
    assert all(expect), expect
