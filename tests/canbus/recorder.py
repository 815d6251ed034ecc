"""Test helpers for buses shared with node processes: a private udp_multicast group, a recorder.

Every test gets its own random multicast group *and* port: on Linux a socket bound to a port
receives every group joined on that port by anyone unless it clears ``IP_MULTICAST_ALL``
(:func:`clutch_ros.canbus.bus.tune_udp_multicast` does; a foreign tool may not).
"""

from __future__ import annotations

import bisect
import random
import socket
import threading
import time

import can
import msgpack

from clutch_ros.canbus.bus import BusConfig, open_bus
from clutch_ros.canbus.udp import malformed_reason, receive_drops


def private_group() -> tuple[str, int]:
    """Return a random (multicast group, UDP port) for one test."""
    rng = random.SystemRandom()
    group = f"239.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
    return group, rng.randint(20000, 60000)


def bus_params(group: str, port: int) -> dict:
    """Node parameters selecting that group."""
    return {"can.interface": "udp_multicast", "can.channel": group, "can.port": port}


def _frame_dict(**changes) -> dict:
    """python-can's udp_multicast datagram fields for a valid 11-bit frame, with ``changes``."""
    fields = {"timestamp": 0.0, "arbitration_id": 0x123, "is_extended_id": False,
              "is_remote_frame": False, "is_error_frame": False, "channel": None, "dlc": 2,
              "data": b"\x01\x02", "is_fd": False, "bitrate_switch": False,
              "error_state_indicator": False}
    fields.update(changes)
    return fields


#: Datagrams that are no CAN frame, with the reason ReconnectingBus must count them under.
MALFORMED_DATAGRAMS: tuple[tuple[str, bytes], ...] = (
    ("not_msgpack", b"\xc1 this is not msgpack"),
    ("not_msgpack", b"\x92"),  # a truncated array
    ("invalid_frame", msgpack.packb(_frame_dict(arbitration_id=0x900), use_bin_type=True)),
    ("invalid_frame", msgpack.packb(_frame_dict(dlc=5), use_bin_type=True)),  # DLC != 2 bytes
    ("invalid_frame", msgpack.packb(_frame_dict(dlc=12, data=bytes(12)), use_bin_type=True)),
    ("not_a_frame", msgpack.packb(42)),
    ("not_a_frame", msgpack.packb(_frame_dict(colour="red"), use_bin_type=True)),
)


class DatagramSender:
    """A plain UDP socket sending raw datagrams to a multicast group (a careless tool)."""

    def __init__(self, group: str, port: int) -> None:
        self.address = (group, port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)

    def send(self, payload: bytes) -> None:
        """Send one datagram."""
        self.sock.sendto(payload, self.address)

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()

    def __enter__(self) -> DatagramSender:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class BusRecorder:
    """Receive every frame of a udp_multicast group on a thread (``frames``: can.Message).

    The frames' timestamps are the kernel receive times, which are the same for every socket
    on the host, so they equal the bus timestamps a node on the same group sees.
    """

    def __init__(self, group: str, port: int) -> None:
        self.bus = open_bus(BusConfig(interface="udp_multicast", channel=group, fd=True,
                                      extra={"port": port}))
        self.frames: list[can.Message] = []
        #: datagrams received that were no CAN frame
        self.malformed = 0
        self._by_id: dict[int, list[can.Message]] = {}  # 11-bit data frames by identifier
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.05)
            except can.CanOperationError as err:
                if malformed_reason(err) is None:
                    raise
                self.malformed += 1  # a datagram that is no CAN frame (a hostile sender)
                continue
            if msg is not None:
                self.frames.append(msg)
                if not (msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id):
                    self._by_id.setdefault(msg.arbitration_id, []).append(msg)

    def drops(self) -> int | None:
        """Frames the kernel dropped at this recorder's socket (it was starved), or None."""
        return receive_drops(self.bus)

    def of(self, arbitration_id: int) -> list[can.Message]:
        """Return the data frames recorded so far with this (11-bit) identifier."""
        return list(self._by_id.get(arbitration_id, ()))

    def count(self, arbitration_id: int) -> int:
        """Return how many data frames with this (11-bit) identifier were recorded."""
        return len(self._by_id.get(arbitration_id, ()))

    def wait_for(self, condition, timeout: float, what: str) -> None:
        """Wait until ``condition()``; raise AssertionError after ``timeout`` [s]."""
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            time.sleep(0.02)

    def close(self) -> None:
        """Stop recording and close the bus."""
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()

    def __enter__(self) -> BusRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def frame_times(frames, db) -> dict[str, list[float]]:
    """Return the recorded bus times [s] of each DBC message (by name), in order."""
    times: dict[str, list[float]] = {}
    for frame in frames:
        if frame.is_error_frame or frame.is_remote_frame:
            continue
        spec = db.lookup(frame.arbitration_id, frame.is_extended_id)
        if spec is not None:
            times.setdefault(spec.name, []).append(frame.timestamp)
    return times


def expected_stale_mask(stamp: float, times: dict[str, list[float]], groups,
                        eps: float = 2e-6) -> int | None:
    """Return the ``stale_mask`` the bus itself gives at ``stamp`` [s]: the oracle.

    ``times``: :func:`frame_times`; ``groups``: ``RigStateAssembler.groups``. Each group is
    aged at ``stamp`` (its oldest frame's newest time up to ``stamp + eps``), as the bridge
    does. None when an age is within 10 us of its limit (float rounding could go either way).
    """
    mask = 0
    for group in groups:
        seen = []
        for name in group.messages:
            ts = times.get(name, [])
            i = bisect.bisect_right(ts, stamp + eps)
            if i:
                seen.append(ts[i - 1])
        if not seen:
            mask |= (1 << group.bit) if group.required and group.messages else 0
            continue
        if len(seen) < len(group.messages):
            mask |= 1 << group.bit
            continue
        age = stamp - min(seen)
        if abs(age - group.max_age) < 1e-5:
            return None
        mask |= (1 << group.bit) if age > group.max_age else 0
    return mask
