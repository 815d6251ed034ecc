"""recv_batch: the same frames, echoes and malformed counts as python-can's recv, in batches."""

import os
import threading
import time
import uuid

import can
import pytest

from clutch_ros.canbus.batch import UdpBatchReader, frame_message, message_frame
from clutch_ros.canbus.bus import BusConfig, ReconnectingBus, open_bus

from .recorder import MALFORMED_DATAGRAMS, DatagramSender, private_group

#: every kind of frame python-can's udp_multicast carries
FRAMES = (
    can.Message(arbitration_id=0x100, is_extended_id=False, data=b"\x01\x02\x03"),
    can.Message(arbitration_id=0x7FF, is_extended_id=False, data=bytes(8)),
    can.Message(arbitration_id=0x18FF0012, is_extended_id=True, data=b"\xAA" * 8),
    can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4),
    can.Message(arbitration_id=0x0, is_extended_id=False, data=b""),
    can.Message(arbitration_id=0x20, is_extended_id=False, is_error_frame=True, data=b"\x00\x04"),
    can.Message(arbitration_id=0x321, is_extended_id=False, is_fd=True, bitrate_switch=True,
                data=bytes(range(12)), dlc=12),
)


def _fields(frame):
    """Everything but the receive time."""
    return frame[1:]


def _read_all(read, want: int, timeout: float = 5.0) -> list:
    out, end = [], time.monotonic() + timeout
    while len(out) < want and time.monotonic() < end:
        out.extend(read())
    return out


def test_batches_equal_python_cans_frames_and_malformed_counts():
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as batched, ReconnectingBus(config) as single, \
            open_bus(config) as peer, DatagramSender(group, port) as junk:
        assert UdpBatchReader.for_bus(batched._bus) is not None  # the fast path is taken
        for _, payload in MALFORMED_DATAGRAMS:
            junk.send(payload)
        for msg in FRAMES * 20:
            peer.send(msg)
        want = len(FRAMES) * 20
        got = _read_all(lambda: batched.recv_batch(0.5, limit=16), want)
        ref = _read_all(lambda: [message_frame(m) for m in [single.recv(0.5)] if m is not None],
                        want)
        assert batched.recv_batch(0.05) == []  # nothing left over
        assert [_fields(f) for f in got] == [_fields(f) for f in ref]
        assert {_fields(f) for f in got} == {_fields(message_frame(m)) for m in FRAMES}
        now = time.time()
        assert all(now - 30.0 < f[0] <= now for f in got)  # kernel receive times
        assert batched.status().malformed_by_reason == single.status().malformed_by_reason
        assert batched.status().malformed_frames == len(MALFORMED_DATAGRAMS)
        assert batched.status().disconnects == 0


def test_a_bus_without_the_udp_socket_goes_through_recv():
    config = BusConfig(interface="virtual", channel=f"v-{uuid.uuid4().hex}")
    with ReconnectingBus(config) as bus, open_bus(config) as peer:
        assert UdpBatchReader.for_bus(bus._bus) is None
        for msg in FRAMES[:3]:
            peer.send(msg)
        got = _read_all(lambda: bus.recv_batch(0.5, limit=2), 3)
        assert [_fields(f) for f in got] == [_fields(message_frame(m)) for m in FRAMES[:3]]


def test_software_filters_keep_python_cans_path():
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port},
                       can_filters=("0x100:0x7FF",))
    with ReconnectingBus(config) as bus, open_bus(BusConfig(
            interface="udp_multicast", channel=group, extra={"port": port})) as peer:
        assert UdpBatchReader.for_bus(bus._bus) is None
        for msg in FRAMES[:3]:
            peer.send(msg)
        got = _read_all(lambda: bus.recv_batch(0.5), 1)
        assert [f[1] for f in got] == [0x100]


def test_a_closed_bus_raises_like_recv():
    group, port = private_group()
    bus = ReconnectingBus(BusConfig(interface="udp_multicast", channel=group,
                                    extra={"port": port}))
    bus.shutdown()
    with pytest.raises(can.CanOperationError):
        bus.recv_batch(0.01)


@pytest.mark.parametrize("msg", FRAMES)
def test_frame_and_message_round_trip(msg):
    again = frame_message(message_frame(msg))
    assert message_frame(again) == message_frame(msg)


def test_a_send_timeout_on_the_socket_does_not_hold_a_batch_back():
    """python-can's send sets a socket timeout; CPython then waits that long before recvmsg."""
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as bus, open_bus(config) as peer:
        bus.send(can.Message(arbitration_id=0x80, is_extended_id=False, data=bytes(8)),
                 timeout=10.0)  # the socket's timeout is now 10 s
        peer.send(FRAMES[0])
        start = time.monotonic()
        got = _read_all(lambda: bus.recv_batch(1.0), 1)
        assert [f[1] for f in got] == [0x100]
        assert time.monotonic() - start < 5.0  # not the socket's 10 s


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_a_blocking_socket_never_holds_an_empty_batch():
    """A send without timeout makes the shared descriptor blocking: reads must not block."""
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as bus, open_bus(config) as peer:
        got = []
        for timeout in (10.0, None):  # the socket's timeout 10 s, then none (blocking)
            bus.send(can.Message(arbitration_id=0x80, is_extended_id=False, data=bytes(8)),
                     timeout=timeout)
            peer.send(FRAMES[0])
            got += _read_all(lambda: bus.recv_batch(1.0), 1)
            reader = bus._readers.reader
            assert reader is not None and reader._own is not None  # one recvmsg a datagram
            done = threading.Event()
            worker = threading.Thread(target=lambda ev=done: (bus.recv_batch(0.0), ev.set()),
                                      daemon=True)
            worker.start()  # nothing queued: returns at once, never waits on the socket
            assert done.wait(5.0), "recv_batch blocked on an empty socket"
        assert [f[1] for f in got] == [0x100, 0x100]


@pytest.fixture
def reading_bus():
    """Yield a bus that has read a frame, its batch reader, and the open fds before it."""
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with open_bus(config) as peer:
        before = _open_fds()
        bus = ReconnectingBus(config)
        peer.send(FRAMES[0])
        assert [f[1] for f in _read_all(lambda: bus.recv_batch(1.0), 1)] == [0x100]
        reader = bus._readers.reader  # (held here: closed, not merely collected)
        assert reader is not None and reader._own is not None
        yield bus, reader, before
        bus.shutdown()


def test_the_readers_own_socket_closes_with_the_bus(reading_bus):
    bus, reader, before = reading_bus
    bus.shutdown()  # no read in progress: closed at once
    assert reader._own.fileno() == -1
    assert _open_fds() == before
    assert bus._readers.reader is None


def test_a_shutdown_during_a_read_leaves_the_close_to_the_reader(reading_bus):
    bus, reader, before = reading_bus
    reading = threading.Thread(target=bus.recv_batch, args=(1.0,), daemon=True)
    reading.start()  # waits up to 1 s for a datagram, the read lock held
    time.sleep(0.2)
    assert bus._readers.lock.locked()
    bus.shutdown()  # cannot close under the read: the reading thread does after it
    reading.join(5.0)
    assert not reading.is_alive()
    assert bus._readers.reader is None
    assert reader._own.fileno() == -1
    assert _open_fds() == before


def test_a_reconnect_closes_the_old_readers_socket(reading_bus):
    bus, reader, _ = reading_bus
    bus._fail(bus._bus, "test: the link dropped")  # as a failed receive does
    bus._next_attempt = 0.0  # reconnect at once (no back-off wait in a test)
    bus.recv_batch(0.05)  # the receive thread's next call: a new bus, a new reader
    assert reader._own.fileno() == -1
    assert bus._readers.reader is not reader and bus._readers.reader is not None


def test_without_a_descriptor_to_spare_the_reader_polls_as_before(monkeypatch):
    """os.dup failing (EMFILE) costs the one-call read, never the frames."""
    import errno

    from clutch_ros.canbus import batch

    def no_dup(_fd):
        raise OSError(errno.EMFILE, "Too many open files")

    monkeypatch.setattr(batch.os, "dup", no_dup)
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as bus, open_bus(config) as peer:
        for msg in FRAMES[:3]:
            peer.send(msg)
        got = _read_all(lambda: bus.recv_batch(0.5), 3)
        assert bus._readers.reader is not None and bus._readers.reader._own is None
        assert [_fields(f) for f in got] == [_fields(message_frame(m)) for m in FRAMES[:3]]
        assert bus.recv_batch(0.05) == []


def test_a_payload_count_of_gigabytes_is_an_invalid_frame_without_allocating_it():
    import resource

    import msgpack

    from .recorder import _frame_dict

    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # [KiB]
    with ReconnectingBus(config) as bus, DatagramSender(group, port) as junk:
        for fields in (_frame_dict(data=2**31, dlc=8), _frame_dict(data=65, dlc=8),
                       _frame_dict(data=2, dlc=2)):  # (an int n: n zero bytes, python-can)
            junk.send(msgpack.packb(fields, use_bin_type=True))
        got = _read_all(lambda: bus.recv_batch(0.5), 1)
        assert [_fields(f) for f in got] == [(0x123, False, False, False, False, 2, bytes(2))]
        assert bus.status().malformed_by_reason == {"invalid_frame": 2}
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown < 200_000, f"{grown} KiB more"  # python-can alone: 2 GiB
