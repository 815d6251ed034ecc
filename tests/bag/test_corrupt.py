"""Corrupt, truncated, inconsistent and foreign bags give specific errors naming the file."""

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_types_from_msg

from clutch_ros.bag.errors import (
    BagCorruptError,
    BagCountMismatchError,
    BagError,
    BagMetadataMismatchError,
    BagNotFoundError,
    UnknownTypeError,
)
from clutch_ros.bag.reader import check_bag, open_bag
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.bag.typestore import RIG_STATE_TYPE, clutch_typestore, rig_state_msg
from clutch_ros.bag.writer import BagWriter

from .conftest import write_sample_bag


def _read_all(path):
    with open_bag(path) as bag:
        return list(bag.messages())


def _edit_metadata(path, edit):
    meta_path = path / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    edit(meta["rosbag2_bagfile_information"])
    meta_path.write_text(yaml.safe_dump(meta))


def test_missing_bag_and_missing_metadata(tmp_path):
    with pytest.raises(BagNotFoundError, match="nowhere: no such bag"):
        open_bag(tmp_path / "nowhere")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagNotFoundError, match="empty_dir: no metadata.yaml"):
        open_bag(tmp_path / "empty_dir")


@pytest.mark.parametrize("keep", [0.6, 0.05])
def test_truncated_mcap(tmp_path, keep):
    path = tmp_path / "trunc"
    write_sample_bag(path)
    file = path / "trunc.mcap"
    data = file.read_bytes()
    file.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(BagCorruptError, match=r"trunc/trunc\.mcap: cannot open bag"):
        _read_all(path)
    with pytest.raises(BagCorruptError, match=r"trunc\.mcap"):
        read_rig_states(path)


@pytest.mark.parametrize("storage, suffix", [("mcap", "mcap"), ("sqlite3", "db3")])
def test_garbage_storage(tmp_path, storage, suffix):
    path = tmp_path / "junk"
    write_sample_bag(path, storage, n=5)
    file = path / f"junk.{suffix}"
    file.write_bytes(np.random.default_rng(1).bytes(file.stat().st_size))
    with pytest.raises(BagCorruptError, match=rf"junk/junk\.{suffix}: cannot open bag"):
        _read_all(path)


def test_unparseable_metadata(tmp_path):
    path = tmp_path / "meta"
    write_sample_bag(path, n=3)
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagCorruptError, match=r"meta/metadata\.yaml: cannot open bag"):
        _read_all(path)


def test_corrupt_record_inside_a_chunk_is_not_silently_dropped(tmp_path):
    """Rosbags skips the rest of a chunk whose record length overruns it, yielding nothing.

    That happens to a chunk without CRC (rosbags writes 0, "not computed"); the CRC that
    BagWriter stores (bag/chunked.py) makes rosbags itself refuse the damaged chunk.
    """
    path = tmp_path / "chunk"
    write_sample_bag(path)
    file = path / "chunk.mcap"
    data = bytearray(file.read_bytes())
    chunk = data.index(b"\x06", 8)  # first chunk record after magic and header
    first_record = chunk + 9 + 28 + 4 + 8  # chunk fields, empty compression string, size
    data[first_record + 1 : first_record + 9] = (10**6).to_bytes(8, "little")
    with_crc = bytes(data)
    assert data[chunk + 33 : chunk + 37] != bytes(4)
    data[chunk + 33 : chunk + 37] = bytes(4)  # as rosbags writes it: no CRC
    file.write_bytes(bytes(data))
    with Reader(path) as raw:
        assert list(raw.messages()) == []  # the silent failure this layer guards against
    with pytest.raises(BagCountMismatchError, match="read 0 messages but the bag declares 50"):
        _read_all(path)
    with pytest.raises(BagCorruptError, match=r"chunk\.mcap: cannot read messages"):
        read_rig_states(path)
    file.write_bytes(with_crc)
    with pytest.raises(BagCorruptError, match=r"chunk\.mcap"):
        _read_all(path)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_metadata_message_count_altered(tmp_path, storage):
    path = tmp_path / "count"
    write_sample_bag(path, storage)

    def bump(meta):
        for topic in meta["topics_with_message_count"]:
            if topic["topic_metadata"]["name"] == "/rig_state":
                topic["message_count"] += 1
        meta["message_count"] += 1

    _edit_metadata(path, bump)
    with pytest.raises(BagCountMismatchError) as err:
        _read_all(path)
    assert err.value.topic == "/rig_state"
    assert (err.value.expected, err.value.actual) == (51, 50)
    assert "count: /rig_state: read 50 messages but the bag declares 51" in str(err.value)
    assert "metadata.yaml declares 51 messages, the storage holds 50" in str(err.value)
    with pytest.raises(BagMetadataMismatchError, match="declares 51 messages, the storage holds"):
        check_bag(path)
    with pytest.raises(BagMetadataMismatchError):
        open_bag(path, verify=True)
    with pytest.raises(BagCountMismatchError, match="declares 51"):
        read_rig_states(path)


def test_check_bag_compares_with_the_counts_written(sample_mcap):
    path, sent = sample_mcap
    counts = check_bag(path, expected={t: len(v) for t, v in sent.items()})
    assert counts["/rig_state"] == 50
    with pytest.raises(BagCountMismatchError, match="/rig_state: 49 messages written"):
        check_bag(path, expected={"/rig_state": 49})


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_metadata_qos_disagreeing_with_storage(tmp_path, storage):
    """Rosbags silently yields nothing for a topic whose metadata QoS differs from storage."""
    path = tmp_path / "qos"
    write_sample_bag(path, storage)

    def best_effort(meta):  # the storage says reliable, as the can_bridge offers rig_state
        for topic in meta["topics_with_message_count"]:
            if topic["topic_metadata"]["name"] == "/rig_state":
                topic["topic_metadata"]["offered_qos_profiles"][0]["reliability"] = "best_effort"

    _edit_metadata(path, best_effort)
    with Reader(path) as raw:
        conns = [c for c in raw.connections if c.topic == "/rig_state"]
        assert conns[0].msgcount == 50 and list(raw.messages(conns)) == []
    with pytest.raises(BagCountMismatchError, match="offered QoS differs") as err:
        _read_all(path)
    assert (err.value.expected, err.value.actual) == (50, 0)
    with pytest.raises(BagCountMismatchError, match="read 0 messages"):
        read_rig_states(path)
    with open_bag(path) as bag:  # the other topics are unaffected
        assert len(list(bag.messages("/clutch_estimate"))) == 25


def _foreign_store(tmp_path, rig_state_extra=False):
    msg_dir = tmp_path / "msgs"
    msg_dir.mkdir()
    text = (
        "std_msgs/Header header\nfloat64 actuating_pressure\n"
        if rig_state_extra
        else "float64 value\n"
    )
    (msg_dir / "RigState.msg").write_text(text)
    store = clutch_typestore(msg_dir)
    if not rig_state_extra:
        store.register(get_types_from_msg("uint32 count\n", "acme_msgs/msg/Foo"))
    return store


def test_unknown_type(tmp_path):
    store = _foreign_store(tmp_path)
    path = tmp_path / "foreign"
    with BagWriter(path, store=store) as writer:
        writer.add_topic("/foo", "acme_msgs/msg/Foo")
        writer.write("/foo", 1, store.types["acme_msgs/msg/Foo"](count=7))
    with pytest.raises(UnknownTypeError, match=r"foreign: topic /foo has type acme_msgs/msg/Foo"):
        _read_all(path)
    with open_bag(path) as bag:  # raw bytes are still available
        ((topic, stamp, data),) = list(bag.messages(raw=True))
    assert (topic, stamp, bytes(data)[4:]) == ("/foo", 1, (7).to_bytes(4, "little"))
    with pytest.raises(BagError, match=f"expected one {RIG_STATE_TYPE} topic, found none"):
        read_rig_states(path)


def test_type_with_a_different_definition(tmp_path):
    store = _foreign_store(tmp_path, rig_state_extra=True)
    path = tmp_path / "old"
    with BagWriter(path, store=store) as writer:
        writer.add_topic("rig_state")
        writer.write("rig_state", 1, store.types[RIG_STATE_TYPE](
            header=clutch_typestore().types["std_msgs/msg/Header"](
                stamp=clutch_typestore().types["builtin_interfaces/msg/Time"](sec=0, nanosec=1),
                frame_id="",
            ),
            actuating_pressure=1.0,
        ))  # fmt: skip
    with pytest.raises(UnknownTypeError, match="differs from the definition in this package"):
        _read_all(path)
    with pytest.raises(UnknownTypeError, match="differs"):
        read_rig_states(path)


def test_undecodable_message_data(tmp_path):
    path = tmp_path / "bad_msg"
    good = bytes(clutch_typestore().serialize_cdr(rig_state_msg(1), RIG_STATE_TYPE))
    with BagWriter(path) as writer:
        writer.add_topic("rig_state")
        writer.write_raw("rig_state", 1, good)
        writer.write_raw("rig_state", 2, good)
        writer.write_raw("rig_state", 3, good[:40])  # truncated CDR
    with pytest.raises(BagCorruptError, match=r"bad_msg\.mcap: message 3 on /rig_state at 3 ns"):
        _read_all(path)
    for fast in (True, False):
        with pytest.raises(BagCorruptError, match="/rig_state: message 3"):
            read_rig_states(path, fast=fast)


def test_missing_storage_file(tmp_path):
    path = tmp_path / "gone"
    write_sample_bag(path, n=2)
    (path / "gone.mcap").unlink()
    with pytest.raises(BagNotFoundError, match=r"gone/gone\.mcap: storage file listed"):
        open_bag(path)
