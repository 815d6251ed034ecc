"""LossTracker: exact gap counts from DDS publication sequence numbers, per publisher."""

from clutch_ros.nodes.loss_tracker import LossTracker, format_counts, parse_counts


def info(seq, gid=b"A"):
    return {"publication_sequence_number": seq, "publisher_gid": {"data": gid}}


def test_gaps_per_publisher_and_late_join():
    t = LossTracker()
    t.add_topic("/a")
    gaps = [t.received("/a", info(s)) for s in (1, 2, 5, 6, 10)]
    assert gaps == [0, 0, 2, 0, 3]
    # a second publisher on the same topic, first seen at seq 4: 3 sent before we saw it
    assert t.received("/a", info(4, b"B")) == 0
    assert t.received("/a", info(5, b"B")) == 0
    assert t.received("/a", info(11)) == 0  # interleaving publishers are no gap
    s = t.topics["/a"]
    assert (s.received, s.dropped, s.missed_at_start, s.publishers) == (8, 5, 3, 2)
    assert t.tracked and t.counts("dropped") == {"/a": 5}


def test_repeated_sample_and_untracked_middleware():
    t = LossTracker()
    assert t.received("/a", info(3)) == 0 and t.received("/a", info(3)) == 0
    assert t.received("/a", info(2)) == 0 and t.received("/a", info(4)) == 0
    assert t.topics["/a"].dropped == 0 and t.topics["/a"].missed_at_start == 2
    t.received("/b", {"publication_sequence_number": None, "publisher_gid": None})
    t.received("/b", None)
    assert t.topics["/b"].untracked == 2 and t.topics["/b"].received == 2 and not t.tracked


def test_counts_format_round_trip():
    counts = {"/rig_state": 5000, "/rig1/clutch_estimate": 0}
    text = format_counts(counts)
    assert text == "/rig1/clutch_estimate=0,/rig_state=5000"
    assert parse_counts(text) == counts and parse_counts("") == {}
