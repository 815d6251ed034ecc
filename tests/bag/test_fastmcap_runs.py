"""The MCAP scan's equal-size record runs find exactly the records of a record-by-record walk.

Chunks are built from MCAP records by hand (channel records and message records of a few
payload sizes, in runs of random lengths, two channels, one of them wanted) and scanned twice:
with run detection, and with it switched off (every record walked in Python, the reference).
Both must give the same message positions, lengths, log times and channels; truncated chunks
must fail the same way.
"""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutch_ros.bag import fastmcap
from clutch_ros.bag.fastmcap import FastMcapError, _Scan


def channel_record(cid: int, topic: str) -> bytes:
    """Return an MCAP channel record (op 0x04) for ``topic``."""
    name = topic.encode()
    body = (struct.pack("<HH", cid, 1) + struct.pack("<I", len(name)) + name
            + struct.pack("<I", 3) + b"cdr" + struct.pack("<I", 0))
    return struct.pack("<BQ", 0x04, len(body)) + body


def message_record(cid: int, seq: int, log_ns: int, payload: bytes) -> bytes:
    """Return an MCAP message record (op 0x05)."""
    body = struct.pack("<HIQQ", cid, seq, log_ns, log_ns) + payload
    return struct.pack("<BQ", 0x05, len(body)) + body


blocks = st.lists(st.tuples(st.integers(1, 40), st.sampled_from([8, 9, 40]),
                            st.sampled_from([1, 2]), st.booleans()), min_size=1, max_size=8)


def build_chunk(spec) -> bytes:
    """Return the records of ``spec``: (count, payload size, channel, channel first) blocks."""
    out, seq = [], 0
    for count, size, cid, with_channel in spec:
        if with_channel:
            out.append(channel_record(3, "/other"))
        for _ in range(count):
            out.append(message_record(cid, seq, 1_000 + 7 * seq, bytes([seq % 251]) * size))
            seq += 1
    return b"".join(out)


def scan(data: bytes, monkeypatch, runs: bool):
    """Scan ``data`` for channel 1 (``/wanted``), with or without run detection."""
    monkeypatch.setattr(fastmcap, "_MIN_RUN", 4 if runs else 10**9)
    sc = _Scan({"/wanted"})
    sc.channel(channel_record(1, "/wanted")[9:])
    sc.channel(channel_record(2, "/unwanted")[9:])
    return sc.records(data)


@settings(max_examples=60, deadline=None)
@given(spec=blocks)
def test_runs_find_the_walks_records(spec):
    data = build_chunk(spec)
    with pytest.MonkeyPatch.context() as mp:
        ref = scan(data, mp, runs=False)
        got = scan(data, mp, runs=True)
    if ref is None:
        assert got is None
        return
    for name in ("starts", "lengths", "times", "channels"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    wanted = sum(count for count, _, cid, _ in spec if cid == 1)
    assert len(ref.starts) == wanted


@pytest.mark.parametrize("cut", [1, 5, 23])
def test_truncated_chunk_fails_with_and_without_runs(monkeypatch, cut):
    data = build_chunk([(30, 9, 1, False)])[:-cut]
    for runs in (False, True):
        with pytest.raises(FastMcapError, match="truncated record|overruns"):
            scan(data, monkeypatch, runs)
