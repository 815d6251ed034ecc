"""BagWriter / BagReader round trips (MCAP and sqlite3), metadata for ros2 bag, mcap reader."""

import sqlite3

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from clutch_ros.bag.errors import BagError, BagExistsError, BagNotFoundError, UnknownTypeError
from clutch_ros.bag.reader import check_bag, open_bag
from clutch_ros.bag.typestore import RIG_STATE_TYPE, rig_state_msg, stamp_to_ns, topic_name
from clutch_ros.bag.writer import BagWriter, write_rig_states
from clutch_ros.errors import ConfigError

from .conftest import STAMP_NS, cdr, write_sample_bag

#: History depth each clutch topic's publisher offers (nodes/*.py), all reliable.
OFFERED_DEPTH = {"/rig_state": 50, "/clutch_estimate": 200, "/torque_request": 200,
                 "/pressure_command": 200, "/pump_request": 50, "/can_frames": 1000,
                 "/diagnostics": 10}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip_identical_messages_and_counts(tmp_path, storage):
    path = tmp_path / f"bag_{storage}"
    sent = write_sample_bag(path, storage)
    with open_bag(path, verify=True) as bag:
        info = bag.topics
        assert {t: i.count for t, i in info.items()} == {t: len(v) for t, v in sent.items()}
        assert bag.message_count == sum(len(v) for v in sent.values())
        assert bag.start_ns == STAMP_NS
        got: dict = {t: [] for t in sent}
        for topic, stamp, msg in bag.messages():
            got[topic].append((stamp, msg))
    for topic, items in sent.items():
        typename = info[topic].typename
        assert [s for s, _ in got[topic]] == [s for s, _ in items], topic
        assert [cdr(m, typename) for _, m in got[topic]] == [cdr(m, typename) for _, m in items]
    assert check_bag(path) == {t: len(v) for t, v in sent.items()}


def test_topic_selection_and_raw_reading(sample_mcap):
    path, sent = sample_mcap
    with open_bag(path) as bag:
        rel = [m for m in bag.messages("rig_state")]  # relative name = /rig_state
        raw = [m for m in bag.messages(["/torque_request"], raw=True)]
        with pytest.raises(BagError, match=r"/nope not in bag \(topics: /can_frames"):
            list(bag.messages("/nope"))
    assert len(rel) == len(sent["/rig_state"]) and {m.topic for m in rel} == {"/rig_state"}
    assert [bytes(m.msg) for m in raw] == [
        cdr(m, "clutch_msgs/msg/TorqueRequest") for _, m in sent["/torque_request"]
    ]


def test_metadata_is_what_ros2_bag_on_jazzy_and_kilted_reads(sample_mcap):
    path, sent = sample_mcap
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["sample_mcap.mcap"]
    total = sum(len(v) for v in sent.values())
    assert meta["message_count"] == total
    assert meta["files"][0]["message_count"] == total
    last = max(s for v in sent.values() for s, _ in v)
    assert meta["starting_time"]["nanoseconds_since_epoch"] == STAMP_NS
    assert meta["duration"]["nanoseconds"] == last - STAMP_NS
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert {n: t["message_count"] for n, t in topics.items()} == {
        n: len(v) for n, v in sent.items()
    }
    for name, entry in topics.items():
        md = entry["topic_metadata"]
        assert md["serialization_format"] == "cdr"
        assert md["type_description_hash"].startswith("RIHS01_")
        (qos,) = md["offered_qos_profiles"]  # v9: a YAML list with policy names
        # what the nodes' publishers offer (every one reliable, REP 2003; rig_state keep last
        # 50 as the can_bridge offers it, not the sensor-data profile of its readers)
        assert qos["reliability"] == "reliable"
        assert qos["depth"] == OFFERED_DEPTH[name]
        assert qos["durability"] == "volatile" and qos["history"] == "keep_last"
        assert qos["liveliness"] == "automatic"
        assert qos["deadline"] == {"sec": 9223372036, "nsec": 854775807}


def test_mcap_opens_with_the_independent_mcap_reader(sample_mcap):
    path, sent = sample_mcap
    with (path / "sample_mcap.mcap").open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        stats = summary.statistics
        assert stats.message_count == sum(len(v) for v in sent.values())
        by_topic = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
        assert by_topic == {t: len(v) for t, v in sent.items()}
        for channel in summary.channels.values():
            (qos,) = yaml.safe_load(channel.metadata["offered_qos_profiles"])
            assert qos["reliability"] in {"reliable", "best_effort"}
        decoded: dict = {t: [] for t in sent}
        for _, channel, message, msg in reader.iter_decoded_messages():
            decoded[channel.topic].append((message.log_time, msg))
    for topic, items in sent.items():
        assert [t for t, _ in decoded[topic]] == [s for s, _ in items]
        for (_, theirs), (_, ours) in zip(decoded[topic], items):
            assert theirs.header.frame_id == ours.header.frame_id
            assert theirs.header.stamp.sec * 10**9 + theirs.header.stamp.nanosec == stamp_to_ns(
                ours.header.stamp
            )
            for name in ours.__dataclass_fields__:
                if name in ("header", "__msgtype__"):
                    continue
                value = getattr(theirs, name)
                if isinstance(value, bytes):  # mcap_ros2 decodes uint8[] as bytes
                    value = np.frombuffer(value, dtype=np.uint8)
                assert np.array_equal(np.asarray(value), np.asarray(getattr(ours, name))), (
                    topic,
                    name,
                )


def test_sqlite3_storage_has_schema_metadata_and_qos(tmp_path):
    path = tmp_path / "sq"
    sent = write_sample_bag(path, "sqlite3", n=5)
    con = sqlite3.connect(path / "sq.db3")
    try:
        assert con.execute("SELECT schema_version FROM schema").fetchone() == (4,)
        assert con.execute("SELECT count(*) FROM metadata").fetchone() == (1,)
        rows = dict(con.execute("SELECT name, offered_qos_profiles FROM topics").fetchall())
        assert yaml.safe_load(rows["/rig_state"])[0]["reliability"] == "reliable"
        assert yaml.safe_load(rows["/rig_state"])[0]["depth"] == 50
        n = con.execute("SELECT count(*) FROM messages").fetchone()[0]
    finally:
        con.close()
    assert n == sum(len(v) for v in sent.values())


def test_existing_output_is_never_overwritten(tmp_path):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("precious")
    with pytest.raises(BagExistsError, match="taken: output exists"):
        BagWriter(tmp_path / "taken")
    assert (tmp_path / "taken" / "keep.txt").read_text() == "precious"
    done = tmp_path / "done"
    write_rig_states(done, [(1, {})])
    with pytest.raises(BagExistsError):
        write_rig_states(done, [(1, {})])


def test_error_inside_writer_keeps_or_deletes_partial_bag(tmp_path):
    for delete in (False, True):
        path = tmp_path / f"partial_{delete}"
        with pytest.raises(RuntimeError), BagWriter(path, delete_on_error=delete) as writer:
            writer.add_topic("rig_state")
            writer.write("rig_state", 1, rig_state_msg(1))
            raise RuntimeError("recorder died")
        assert path.exists() is not delete
        if not delete:
            with pytest.raises(BagNotFoundError, match="no metadata.yaml"):
                open_bag(path)


def test_writer_rejects_misuse(tmp_path):
    with pytest.raises(ConfigError, match="unknown bag storage 'rosbag1'"):
        BagWriter(tmp_path / "x", storage="rosbag1")
    with BagWriter(tmp_path / "w") as writer:
        with pytest.raises(UnknownTypeError, match="no message type given for topic /foo"):
            writer.add_topic("foo")
        with pytest.raises(UnknownTypeError, match="acme_msgs/msg/Foo"):
            writer.add_topic("foo", "acme_msgs/msg/Foo")
        with pytest.raises(BagError, match="/rig_state was not added"):
            writer.write("rig_state", 0, rig_state_msg(0))
        name = writer.add_topic("rig_state")
        with pytest.raises(BagError, match="already added as"):
            writer.add_topic("rig_state", "clutch_msgs/msg/TorqueRequest")
        with pytest.raises(BagError, match="serialize"):
            writer.write(name, 0, object())
        with pytest.raises(BagError, match="negative timestamp"):
            writer.write(name, -5, rig_state_msg(0))
    assert writer.written == {"/rig_state": 0}


def test_topic_names_are_stored_absolute():
    assert topic_name("rig_state") == "/rig_state"
    assert topic_name("/rig_state") == "/rig_state"
    assert topic_name("rig_state", "/rig1") == "/rig1/rig_state"
    with pytest.raises(ConfigError):
        topic_name(" ")


def test_namespaced_topic_keeps_default_type_and_qos(tmp_path):
    path = tmp_path / "ns"
    with BagWriter(path, namespace="/rig1") as writer:
        name = writer.add_topic("rig_state")
        writer.write(name, 5, rig_state_msg(5))
    with open_bag(path) as bag:
        (info,) = bag.topics.values()
    assert info.topic == "/rig1/rig_state" and info.typename == RIG_STATE_TYPE
    assert info.qos[0].reliability.name == "RELIABLE" and info.qos[0].depth == 50


def test_custom_data_is_stored(tmp_path):
    path = tmp_path / "c"
    write_rig_states(path, [(1, {"slip_speed": 2.0})], custom_data={"clutch_ros.source": "x.csv"})
    with open_bag(path) as bag:
        assert bag.custom_data == {"clutch_ros.source": "x.csv"}
        ((_, stamp, msg),) = list(bag.messages())
    assert stamp == 1 and msg.slip_speed == 2.0 and msg.header.frame_id == "rig"


def test_dropped_messages_are_recorded_in_the_bag(tmp_path):
    path = tmp_path / "drops"
    with BagWriter(path) as writer:
        writer.add_topic("rig_state")
        writer.write("rig_state", 1, rig_state_msg(1))
        writer.mark_dropped("rig_state", 3)
        writer.mark_dropped("/clutch_estimate")
    assert writer.dropped == {"/rig_state": 3, "/clutch_estimate": 1}
    with open_bag(path) as bag:
        assert bag.custom_data["clutch_ros.dropped"] == "/clutch_estimate=1,/rig_state=3"
