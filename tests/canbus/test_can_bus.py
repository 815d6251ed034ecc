"""BusConfig, open_bus and ReconnectingBus over a python-can interface with a pluggable adapter."""

import logging
import threading
import time
import uuid

import can
import can.interfaces
import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.bus import (
    BusConfig,
    EchoFilter,
    LinkState,
    ReconnectingBus,
    open_bus,
    parse_filters,
)
from clutch_ros.canbus.errors import BusConfigError, BusUnavailable
from clutch_ros.canbus.udp import malformed_reason
from clutch_ros.errors import ConfigError

from . import flaky_bus
from .flaky_bus import ADAPTERS, Adapter
from .recorder import MALFORMED_DATAGRAMS, DatagramSender, private_group


class FakeClock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture
def adapter(monkeypatch):
    """Register the ``flaky`` interface and return (config, adapter, wire channel)."""
    monkeypatch.setitem(can.interfaces.BACKENDS, "flaky", (flaky_bus.__name__, "FlakyBus"))
    name = f"flaky-{uuid.uuid4().hex}"
    ADAPTERS[name] = Adapter()
    yield BusConfig(interface="flaky", channel=name), ADAPTERS[name], f"{name}-wire"
    del ADAPTERS[name]


def test_bus_config_validation():
    with pytest.raises(BusConfigError, match="socketcan"):
        BusConfig(interface="nonexistent")
    with pytest.raises(ConfigError):
        BusConfig(interface="virtual", bitrate=-5)
    with pytest.raises(BusConfigError):
        BusConfig(interface="virtual", bitrate=True)
    with pytest.raises(BusConfigError):
        BusConfig(interface="virtual", data_bitrate=2_000_000)
    with pytest.raises(BusConfigError):
        BusConfig(interface="virtual", extra={"channel": "x"})
    with pytest.raises(BusConfigError):
        BusConfig(interface="udp_multicast", channel="239.0.0.1", receive_own_messages=True)
    with pytest.raises(BusConfigError):
        BusConfig(interface="virtual", can_filters=["0x100"])
    config = BusConfig(interface="socketcan", channel="can0", bitrate=1_000_000,
                       can_filters=["0x100:0x7F0", {"can_id": 0x80, "can_mask": 0x7FE}],
                       extra={"local_loopback": False})
    assert config.kwargs() == {
        "interface": "socketcan", "channel": "can0", "receive_own_messages": False,
        "bitrate": 1_000_000, "local_loopback": False,
        "can_filters": [{"can_id": 0x100, "can_mask": 0x7F0},
                        {"can_id": 0x80, "can_mask": 0x7FE}],
    }


def test_parse_filters():
    assert parse_filters(["0x18EBFF00:0x1FFFFFFF:x"]) == (
        {"can_id": 0x18EBFF00, "can_mask": 0x1FFFFFFF, "extended": True},)
    for bad in (["1:2:3"], ["zz:1"], [{"can_id": 1}], [{"can_id": 1 << 30, "can_mask": 0}],
                [{"can_id": 1, "can_mask": 1, "bogus": 1}], [42]):
        with pytest.raises(BusConfigError):
            parse_filters(bad)


def test_open_bus_applies_filters(channel):
    config = BusConfig(interface="virtual", channel=channel, can_filters=["0x100:0x7FF"])
    with open_bus(config) as rx, can.Bus(interface="virtual", channel=channel) as tx:
        tx.send(can.Message(arbitration_id=0x200, data=b"\x01"))
        tx.send(can.Message(arbitration_id=0x100, data=b"\x02"))
        msg = rx.recv(1.0)
        assert msg.arbitration_id == 0x100
        assert rx.recv(0.05) is None


def test_open_bus_wraps_errors(adapter):
    config, adapt, _ = adapter
    adapt.plugged = False
    with pytest.raises(BusUnavailable, match=config.channel) as info:
        open_bus(config)
    assert isinstance(info.value.__cause__, can.CanInitializationError)
    with pytest.raises(BusUnavailable, match="clutchtest9"):
        open_bus(BusConfig(interface="socketcan", channel="clutchtest9"))
    with pytest.raises(BusUnavailable, match="struct.error|error"):  # any driver error
        open_bus(BusConfig(interface="udp_multicast", channel="239.1.2.3",
                           extra={"hop_limit": -3}))


def test_open_bus_rejected_arguments(monkeypatch):
    monkeypatch.setitem(can.interfaces.BACKENDS, "picky", (flaky_bus.__name__, "PickyBus"))
    with pytest.raises(BusConfigError, match="invalid bus arguments") as info:
        open_bus(BusConfig(interface="picky", channel="x"))
    assert isinstance(info.value.__cause__, TypeError)


def drive(bus, clock, seconds, step=0.05):
    """Advance the fake clock in steps, polling recv(0) like a Notifier thread would."""
    for _ in range(round(seconds / step)):
        clock.t += step
        bus.recv(0)


def test_backoff_reconnect_and_no_storm(adapter, caplog):
    config, adapt, _ = adapter
    clock = FakeClock()
    adapt.clock = clock
    events = []
    caplog.set_level(logging.DEBUG, logger="clutch_ros.canbus.bus")
    bus = ReconnectingBus(config, clock=clock, sleep=lambda s: None, backoff_initial=0.1,
                          backoff_max=1.0, report_interval=2.0, on_event=events.append)
    try:
        assert bus.link_state == LinkState.UP
        adapt.plugged = False  # pull the USB adapter
        assert bus.recv(0) is None  # OSError inside recv: handled, link down
        assert bus.link_state == LinkState.DOWN
        t_down = clock.t
        del adapt.open_attempts[:]
        drive(bus, clock, 8.0, step=0.01)
        gaps = [round(b - a, 2) for a, b in zip([t_down, *adapt.open_attempts],
                                                adapt.open_attempts)]
        # exponential back-off, capped; the 10 ms polling step is the only slack
        assert gaps[:5] == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.0], abs=0.011)
        assert gaps[4:] == pytest.approx([1.0] * len(gaps[4:]), abs=0.011)
        assert bus.status().failed_attempts == len(gaps)
        adapt.plugged = True
        drive(bus, clock, 1.1)
        assert bus.link_state == LinkState.UP
        assert [(e.old, e.new) for e in events] == [
            (LinkState.CONNECTING, LinkState.UP), (LinkState.UP, LinkState.DOWN),
            (LinkState.DOWN, LinkState.UP)]
        assert "receive failed" in events[1].reason and "No such device" in events[1].reason
        warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
        assert len(gaps) >= 10
        assert 1 <= len(warnings) <= 8 / 2.0 + 2  # rate limited: ~1 per report_interval
        assert bus.connects == 2 and bus.disconnects == 1
    finally:
        bus.shutdown()
    assert bus.link_state == LinkState.CLOSED
    with pytest.raises(can.CanOperationError):
        bus.recv(0)


def test_unavailable_at_start_never_raises(adapter):
    config, adapt, _ = adapter
    adapt.plugged = False
    clock = FakeClock()
    with ReconnectingBus(config, clock=clock, sleep=lambda s: None) as bus:
        assert bus.link_state == LinkState.DOWN
        assert bus.recv(0) is None
        assert not bus.try_send(can.Message(arbitration_id=1))
        status = bus.status()
        assert status.state == LinkState.DOWN and status.bus_state == "ERROR"
        assert "not found" in status.reason and status.next_attempt_in == pytest.approx(0.1)
        adapt.plugged = True
        clock.t += 0.1
        assert bus.try_send(can.Message(arbitration_id=1))
        assert bus.link_state == LinkState.UP


def test_send_failures_take_link_down(adapter):
    config, adapt, wire = adapter
    clock = FakeClock()
    with ReconnectingBus(config, clock=clock, sleep=lambda s: None, max_send_failures=3) as bus, \
            can.Bus(interface="virtual", channel=wire) as peer:
        msg = can.Message(arbitration_id=0x80, data=bytes(8))
        bus.send(msg)
        assert peer.recv(1.0).arbitration_id == 0x80
        adapt.fail_send = True
        with pytest.raises(BusUnavailable) as info:
            bus.send(msg)
        assert isinstance(info.value.__cause__, can.CanOperationError)
        assert not bus.try_send(msg)
        assert bus.link_state == LinkState.UP  # 2 failures: still up
        assert not bus.try_send(msg)
        assert bus.link_state == LinkState.DOWN  # the 3rd closes and schedules a reopen
        with pytest.raises(BusUnavailable, match="down"):
            bus.send(msg)
        adapt.fail_send = False
        clock.t += 0.1
        assert bus.try_send(msg)
        assert bus.link_state == LinkState.UP and bus.send_failures == 4


def test_bus_off_from_controller_state(adapter):
    config, adapt, _ = adapter
    clock = FakeClock()
    with ReconnectingBus(config, clock=clock, sleep=lambda s: None,
                         state_poll_interval=0.5) as bus:
        adapt.state = can.BusState.ERROR
        clock.t += 0.1
        bus.recv(0)
        assert bus.link_state == LinkState.UP  # not polled yet
        clock.t += 0.5
        bus.recv(0)
        assert bus.link_state == LinkState.DOWN and "bus-off" in bus.status().reason
        clock.t += 0.1
        bus.recv(0)
        assert bus.link_state == LinkState.UP and bus.state == can.BusState.ACTIVE


def test_bus_off_error_frame(adapter):
    config, _, wire = adapter
    clock = FakeClock()
    with ReconnectingBus(config, clock=clock, sleep=lambda s: None,
                         socketcan_error_frames=True) as bus, \
            can.Bus(interface="virtual", channel=wire) as peer:
        peer.send(can.Message(arbitration_id=0x04, is_error_frame=True, data=bytes(8)))
        assert bus.recv(1.0).is_error_frame
        assert bus.link_state == LinkState.UP  # controller problem, not bus-off
        peer.send(can.Message(arbitration_id=0x40, is_error_frame=True, data=bytes(8)))
        assert bus.recv(1.0).is_error_frame  # the frame itself is still delivered
        assert bus.link_state == LinkState.DOWN and bus.bus_off_frames == 1


def test_notifier_survives_unplug_with_real_clock(adapter, db):
    config, adapt, wire = adapter
    assembler = RigStateAssembler(db)
    bus = ReconnectingBus(config, backoff_initial=0.01, backoff_max=0.05)
    peer = can.Bus(interface="virtual", channel=wire)
    frame = db.make_message("TorqueRequest", {"TorqueRequest": 42.0})
    notifier = can.Notifier(bus, [assembler], timeout=0.02)
    try:
        peer.send(frame)
        deadline = time.monotonic() + 5
        while assembler.counters().decoded_frames < 1 and time.monotonic() < deadline:
            time.sleep(0.005)
        adapt.plugged = False
        time.sleep(0.3)
        assert bus.link_state == LinkState.DOWN
        adapt.plugged = True
        deadline = time.monotonic() + 5
        while bus.link_state != LinkState.UP and time.monotonic() < deadline:
            time.sleep(0.005)
        peer.send(frame)
        while assembler.counters().decoded_frames < 2 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert assembler.counters().decoded_frames == 2
        assert notifier.exception is None and not notifier.stopped
        assert bus.connects == 2
    finally:
        notifier.stop()
        bus.shutdown()
        peer.shutdown()


def test_shutdown_wakes_a_waiting_receiver(adapter):
    config, adapt, _ = adapter
    adapt.plugged = False
    bus = ReconnectingBus(config, backoff_initial=30.0, backoff_max=30.0)
    result = []

    def receive():
        try:
            result.append(bus.recv(10.0))
        except can.CanOperationError as err:
            result.append(err)

    thread = threading.Thread(target=receive)
    thread.start()
    time.sleep(0.05)
    start = time.monotonic()
    bus.shutdown()
    thread.join(2.0)
    assert not thread.is_alive() and time.monotonic() - start < 1.0
    assert isinstance(result[0], can.CanOperationError)


def test_broken_event_callback_is_contained(adapter):
    config, adapt, _ = adapter

    def explode(event):
        raise RuntimeError("callback bug")

    clock = FakeClock()
    with ReconnectingBus(config, clock=clock, sleep=lambda s: None, on_event=explode) as bus:
        adapt.plugged = False
        assert bus.recv(0) is None
        assert bus.link_state == LinkState.DOWN


def test_echo_filter_unit():
    clock = FakeClock()
    echo = EchoFilter(clock, window=1.0, capacity=3)
    a = can.Message(arbitration_id=0x80, data=b"\x01\x02")
    b = can.Message(arbitration_id=0x80, data=b"\x01\x03")
    assert not echo.is_echo(a)  # nothing sent yet
    assert echo.pending_ids() == frozenset()
    echo.sent(a)
    echo.sent(a)
    assert echo.pending_ids() == {0x80}  # recv_batch passes other identifiers unchecked
    # the timestamp is the receiver's: 0.5 s after the send it is still this frame's echo
    assert echo.is_echo(can.Message(arbitration_id=0x80, data=b"\x01\x02",
                                    timestamp=clock.t + 0.5))
    assert echo.is_echo(a) and not echo.is_echo(a)  # once per copy sent
    assert not echo.is_echo(can.Message(arbitration_id=0x80, data=b"\x01\x02",
                                        is_extended_id=True))
    echo.sent(b)
    echo.unsent(b)  # the send failed: no echo will come
    assert not echo.is_echo(b)
    echo.sent(b)
    clock.t += 1.5  # too old: a foreign frame that happens to be equal is not swallowed
    assert not echo.is_echo(b)
    for i in range(5):  # bounded memory
        echo.sent(can.Message(arbitration_id=i))
    assert not echo.is_echo(can.Message(arbitration_id=0))
    assert echo.is_echo(can.Message(arbitration_id=4))
    assert echo.echoes == 3


def test_echo_filter_expires_in_stream_time_so_a_late_reader_meets_its_echoes():
    """Records expire by the received frames' timestamps, not by the clock of a late reader."""
    clock = FakeClock()
    echo = EchoFilter(clock, window=1.0)
    mine = can.Message(arbitration_id=0x80, data=b"\x05", timestamp=0.0)
    echo.sent(mine)  # sent at t = 1000.0 (kernel time of its echo: the same)
    clock.t += 5.0  # the reader is 5 s behind: 5 s of other frames were queued before the echo
    other = can.Message(arbitration_id=0x81, data=b"\x01", timestamp=1000.0)
    assert not echo.is_echo(other)
    echo_back = can.Message(arbitration_id=0x80, data=b"\x05", timestamp=1000.0001)
    assert echo.is_echo(echo_back)
    # the control: a frame received 1.5 s after a send is another node's, even when equal
    echo.sent(mine)
    clock.t += 0.1
    assert not echo.is_echo(can.Message(arbitration_id=0x80, data=b"\x05",
                                        timestamp=clock.t + 1.4))
    assert echo.echoes == 1


def test_udp_multicast_echo_removed_and_groups_isolated():
    """python-can's udp_multicast loops our frames back; ReconnectingBus drops exactly those."""
    pytest.importorskip("msgpack", reason="python-can's udp_multicast needs msgpack")
    group, port = private_group()
    other = f"{group.rsplit('.', 1)[0]}.{(int(group.rsplit('.', 1)[1]) % 254) + 1}"
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    with ReconnectingBus(config) as bridge, open_bus(config) as peer, \
            open_bus(BusConfig(interface="udp_multicast", channel=other,
                               extra={"port": port})) as stranger:
        mine = [can.Message(arbitration_id=0x80, data=bytes([i, 1])) for i in range(20)]
        theirs = can.Message(arbitration_id=0x100, data=b"\x05")
        for msg in mine:
            bridge.send(msg)
        peer.send(theirs)
        got = []
        while (msg := bridge.recv(0.3)) is not None:
            got.append(msg)
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x100, b"\x05")]
        assert bridge.own_echoes == 20 and bridge.status().own_echoes == 20
        # the peer (a plain python-can bus) hears them all, and its own echo
        heard = []
        while (msg := peer.recv(0.3)) is not None:
            heard.append(msg.arbitration_id)
        assert heard.count(0x80) == 20 and heard.count(0x100) == 1
        # same port, another group: nothing crosses (IP_MULTICAST_ALL cleared)
        assert stranger.recv(0.3) is None
    # receive_own_messages=False is the default: a plain BusConfig keeps the filter off
    # for interfaces that do not echo
    with ReconnectingBus(BusConfig(interface="virtual", channel=f"v-{uuid.uuid4().hex}")) as v:
        v.send(can.Message(arbitration_id=1))
        assert v.own_echoes == 0


def test_malformed_datagrams_are_counted_and_dropped_not_a_link_failure(caplog):
    """Finding 1: one bad datagram used to take the udp_multicast link down and reconnect."""
    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    good = [can.Message(arbitration_id=0x100 + i, data=bytes([i])) for i in range(3)]
    with ReconnectingBus(config, report_interval=60.0) as bus, open_bus(config) as peer, \
            DatagramSender(group, port) as junk, caplog.at_level(logging.WARNING):
        for _ in range(3):
            for _, payload in MALFORMED_DATAGRAMS:
                junk.send(payload)
        for msg in good:
            peer.send(msg)
        got = []
        while (msg := bus.recv(0.5)) is not None:
            got.append(msg)
        status = bus.status()
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [
        (m.arbitration_id, bytes(m.data)) for m in good]
    expected = {}
    for reason, _ in MALFORMED_DATAGRAMS:
        expected[reason] = expected.get(reason, 0) + 3
    assert status.malformed_by_reason == expected
    assert status.malformed_frames == 3 * len(MALFORMED_DATAGRAMS)
    assert status.state == LinkState.UP and status.disconnects == 0 and status.connects == 1
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "malformed" in warnings[0].getMessage()  # no storm


def test_transport_failure_still_takes_the_link_down(adapter):
    """A receive error caused by the OS (or without a cause) is a link failure, as before."""
    config, plug, _ = adapter
    with ReconnectingBus(config, clock=FakeClock(), sleep=lambda s: None) as bus:
        plug.plugged = False
        bus.recv(0.0)
        assert bus.status().state == LinkState.DOWN and bus.malformed_frames == 0


def test_malformed_reason_tells_transport_from_datagram_errors():
    def wrapped(cause):
        try:
            try:
                raise cause
            except Exception as err:
                raise can.CanOperationError("wrapped") from err
        except can.CanOperationError as outer:
            return outer

    assert malformed_reason(wrapped(OSError(100, "Network is down"))) is None
    assert malformed_reason(wrapped(can.CanOperationError("socket"))) is None
    assert malformed_reason(can.CanOperationError("no cause")) is None
    assert malformed_reason(OSError(19, "No such device")) is None
    assert malformed_reason(wrapped(ValueError("Unpack failed"))) == "not_msgpack"
    assert malformed_reason(wrapped(TypeError("bad keyword"))) == "not_a_frame"


def test_bus_config_from_node_params():
    config = BusConfig.from_params({"can.interface": "udp_multicast", "can.channel": "239.1.2.3",
                                    "can.port": 40000, "can.bitrate": 0, "can.fd": False,
                                    "can.receive_own_messages": False, "can.filters": [""]})
    assert config.kwargs() == {"interface": "udp_multicast", "channel": "239.1.2.3",
                               "receive_own_messages": False, "port": 40000}
    config = BusConfig.from_params({"can.interface": "socketcan", "can.channel": "can0",
                                    "can.port": 40000, "can.bitrate": 500000, "can.fd": True,
                                    "can.filters": ["0x100:0x7F0", ""]})
    assert config.bitrate == 500000 and config.fd and config.extra == {}
    assert config.can_filters == ({"can_id": 0x100, "can_mask": 0x7F0},)
    with pytest.raises(BusConfigError, match="CAN filter"):
        BusConfig.from_params({"can.interface": "virtual", "can.filters": ["0x100"]})


def test_receive_drops_account_for_every_datagram_the_kernel_dropped():
    """A reader that falls behind: frames read + frames the kernel dropped = frames sent.

    The receive buffer is shrunk to 4 KiB so that a 500-frame burst overflows it for sure
    (the real buffer is 4 MiB; a starved process overflows that at 10,000 frames/s too), and
    the bus is reconnected once in between: the drops of the closed socket still count.
    """
    import socket

    group, port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": port})
    rx = ReconnectingBus(config)
    try:
        assert rx.status().receive_drops == 0

        def burst(count: int) -> int:
            rx._bus._multicast._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            with open_bus(config) as tx:
                for i in range(count):
                    tx.send(can.Message(arbitration_id=0x123, data=i.to_bytes(8, "little"),
                                        is_extended_id=False))
            time.sleep(0.2)  # every datagram delivered or dropped by now (loopback)
            read = 0
            while rx.recv(0.1) is not None:
                read += 1
            return read

        first = burst(500)
        dropped_first = rx.status().receive_drops
        assert first + dropped_first == 500 and dropped_first > 0, (first, dropped_first)
        rx._fail(rx._bus, "test: reconnect")  # the next recv opens a new socket
        deadline = time.monotonic() + 10.0  # it retries after its back-off (0.1 s)
        while rx.status().state != LinkState.UP and time.monotonic() < deadline:
            assert rx.recv(0.05) is None
        assert rx.status().state == LinkState.UP and rx.connects == 2
        second = burst(300)
        assert first + second + rx.status().receive_drops == 800
        assert rx.status().receive_drops > dropped_first
    finally:
        rx.shutdown()


def test_receive_drops_unknown_for_an_interface_that_cannot_tell():
    bus = ReconnectingBus(BusConfig(interface="virtual", channel=f"drops-{uuid.uuid4()}"))
    try:
        assert bus.status().receive_drops is None
    finally:
        bus.shutdown()
