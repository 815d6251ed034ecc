"""recv_columns (recvmmsg + compiled parse) against recv_batch on the same datagrams.

Two buses join one multicast group and receive the same datagrams: python-can's frames of
every kind, malformed datagrams, and msgpack maps in every layout the compiled parser must
either read exactly or leave to the Python path (str channels, other int widths, duplicate
keys, trailing bytes, map16, bools where ints belong...). The frames (in order), the
malformed counts and the echoes removed must be the same.
"""

from __future__ import annotations

import dataclasses
import time

import can
import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutch_ros.canbus.bus import BusConfig, ReconnectingBus, open_bus
from clutch_ros.canbus.intake import Columns, frame_at
from clutch_ros.canbus.udp_columns import available

from .recorder import MALFORMED_DATAGRAMS, DatagramSender, _frame_dict, private_group
from .test_batch import FRAMES

pytestmark = pytest.mark.skipif(not available(), reason="recvmmsg or numba not available")


def _as_frames(got) -> list:
    if isinstance(got, Columns):
        return [frame_at(got, i) for i in range(got.stamp.size)]
    return list(got)


def _read(read, want: int, timeout: float = 5.0) -> list:
    out, end = [], time.monotonic() + timeout
    while len(out) < want and time.monotonic() < end:
        out.extend(_as_frames(read()))
    return out


def _values_of(frame) -> tuple:
    """Return a frame's fields as the columns hold them.

    python-can keeps what a map gave: an ``is_error_frame`` of 300 stays 300 in a Message,
    a truthy flag in the columns.
    """
    _, ident, ext, remote, error, fd, dlc, data = frame
    return int(ident), bool(ext), bool(remote), bool(error), bool(fd), int(dlc), bytes(data)


def _pack(fields: dict) -> bytes:
    return msgpack.packb(fields, use_bin_type=True)


#: layouts the compiled parser must get right or hand over (each a valid or invalid frame)
ODD_DATAGRAMS = (
    _pack(_frame_dict(channel="can0")),  # a str channel: Python path, a frame
    _pack(_frame_dict(channel=3)),
    _pack(_frame_dict(timestamp=17)),  # an int time
    _pack(_frame_dict(timestamp=None)),
    _pack(_frame_dict(arbitration_id=0x7FF)),  # uint16
    _pack(_frame_dict(arbitration_id=0x1FFFFFFF, is_extended_id=True)),  # uint32
    _pack(_frame_dict(arbitration_id=2**40, is_extended_id=True)),  # uint64: invalid
    _pack(_frame_dict(arbitration_id=-1)),  # negative: invalid
    _pack(_frame_dict(arbitration_id=True)),  # a bool: invalid
    _pack(_frame_dict(dlc=2.0)),  # a float DLC: Python's checks
    _pack(_frame_dict(data="ab")),  # a str payload
    _pack(_frame_dict(is_fd=1)),  # an int flag
    _pack(_frame_dict(is_remote_frame=True, dlc=3, data=b"")),
    _pack(_frame_dict(is_remote_frame=True, is_error_frame=True, dlc=0, data=b"")),
    _pack(_frame_dict(bitrate_switch=True)),  # BRS without FD: invalid
    _pack(_frame_dict(is_fd=True, dlc=12, data=bytes(12))),  # FD on a classic bus: ignored
    _pack(_frame_dict(data=bytes(300), dlc=300)),  # bin16 payload: invalid
    _pack(_frame_dict()) + b"\x00",  # trailing byte
    _pack(_frame_dict())[:-1],  # truncated
    b"\xde\x00\x0b" + _pack(_frame_dict())[1:],  # map16 of the same 11 entries
    _pack({**_frame_dict(), "extra": 1}),  # a 12th key
    _pack({k: v for k, v in _frame_dict().items() if k != "channel"}),  # 10 keys
    b"\x8b" + _pack(_frame_dict())[1:30] + _pack(_frame_dict())[1:30],  # duplicate keys
    _pack(_frame_dict(data=b"\xff" * 8, dlc=8, arbitration_id=0x100)),
)


def _pair(fd: bool = False):
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, fd=fd, extra={"port": port})
    return config, ReconnectingBus(config), ReconnectingBus(config), DatagramSender(group, port)


def _compare(datagrams: list[bytes], frames: tuple[can.Message, ...], fd: bool = False) -> list:
    config, columns_bus, batch_bus, junk = _pair(fd)
    with columns_bus, batch_bus, junk, open_bus(dataclasses.replace(config, fd=True)) as peer:
        for msg in frames:
            peer.send(msg)
        for payload in datagrams:
            junk.send(payload)
        time.sleep(0.05)
        want = len(frames) + len(datagrams)  # an upper bound: malformed ones are dropped
        start = time.time()
        ref = _read(lambda: batch_bus.recv_batch(0.2, limit=32), want, timeout=1.0)
        got = _read(lambda: columns_bus.recv_columns(0.2, limit=32), want, timeout=1.0)
        assert [_values_of(f) for f in got] == [_values_of(f) for f in ref]
        now = time.time()
        assert all(now - 30.0 < f[0] <= now for f in got)  # kernel receive times
        # Both are the kernel's stamps of the same datagram, normally equal. A datagram that
        # came before the kernel had switched its receive timestamps on (deferred work after
        # the first socket asks for them; late on a busy machine) is stamped when each socket
        # reads it (net/socket.c, __sock_recv_timestamp): up to the reads' span apart.
        for a, b in zip(got, ref, strict=True):
            assert abs(a[0] - b[0]) <= max(0.5, now - start)
        assert columns_bus.status().malformed_by_reason == batch_bus.status().malformed_by_reason
        assert columns_bus.status().disconnects == 0
        return got


def test_columns_equal_the_batches_frames_and_malformed_counts() -> None:
    got = _compare([p for _, p in MALFORMED_DATAGRAMS] + list(ODD_DATAGRAMS), FRAMES * 20)
    assert len(got) > len(FRAMES) * 20 - 20  # the frames came (the FD one is ignored)


def test_an_fd_bus_keeps_fd_frames() -> None:
    got = _compare(list(ODD_DATAGRAMS), FRAMES, fd=True)
    assert any(f[5] for f in got)


@pytest.mark.parametrize("reader", ["recv_batch", "recv_columns"])
def test_own_frames_are_removed_others_kept(reader: str) -> None:
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as bus, open_bus(config) as peer:
        read = getattr(bus, reader)
        own = can.Message(arbitration_id=0x80, is_extended_id=False, data=bytes(8))
        bus.send(own)
        peer.send(own)  # the same frame from another node: kept
        got = _read(lambda: read(0.5), 1)
        time.sleep(0.1)
        got += _as_frames(read(0.1))
        assert [f[1:] for f in got] == [(0x80, False, False, False, False, 8, bytes(8))]
        assert bus.own_echoes == 1


_values = st.one_of(st.none(), st.booleans(), st.integers(-2**40, 2**40),
                    st.floats(allow_nan=False), st.binary(max_size=10), st.text(max_size=4))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.dictionaries(st.sampled_from(sorted(_frame_dict())), _values, max_size=11)
                .map(lambda d: {**_frame_dict(), **d}), min_size=1, max_size=12))
def test_any_map_gives_the_python_paths_frames(maps: list[dict]) -> None:
    _compare([_pack(m) for m in maps], ())


def test_a_payload_count_of_gigabytes_is_an_invalid_frame_without_allocating_it() -> None:
    import resource

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # [KiB]
    datagrams = [_pack(_frame_dict(data=2**31, dlc=8)), _pack(_frame_dict(data=65, dlc=8)),
                 _pack(_frame_dict(data=2, dlc=2))]  # (an int n: n zero bytes, python-can)
    got = _compare(datagrams, ())
    assert [_values_of(f) for f in got] == [(0x123, False, False, False, False, 2, bytes(2))]
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown < 200_000, f"{grown} KiB more"  # python-can alone: 2 GiB per bus
