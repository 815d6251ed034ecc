"""A minimal Foxglove WebSocket client (``websockets``), speaking the protocol itself.

Independent of foxglove-sdk on purpose: it checks what goes over the wire (the ws-protocol
spec, subprotocol ``foxglove.sdk.v1``). JSON text frames: ``serverInfo``, ``advertise``
(channels with ``encoding``, ``schemaName``, ``schemaEncoding``, ``schema``), ``subscribe``,
``status``, ``getParameters``/``setParameters`` -> ``parameterValues``, client ``advertise``.
Binary frames, little endian. Server: opcode 1 message data (u32 subscription id, u64 log time
[ns], payload), 2 time (u64 [ns]), 5 playback state (u8 status, u64 current time [ns], f32
speed, u8 did seek, u32 length + request id). Client: opcode 1 message data (u32 client
channel id, payload), 3 playback control request (u8 command 0 play / 1 pause, f32 speed,
u8 had seek, u64 seek time [ns], u32 length + request id).
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import time

import websockets
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

SUBPROTOCOL = "foxglove.sdk.v1"
_HEADER = struct.Struct("<BIQ")
_TIME = struct.Struct("<BQ")
_STATE = struct.Struct("<BBQfBI")
_CONTROL = struct.Struct("<BBfBQI")
PLAYBACK_STATUS = {0: "playing", 1: "paused", 2: "buffering", 3: "ended"}


class FoxgloveClient:
    """One connection: channels advertised, subscriptions, and what arrived per topic."""

    def __init__(self, url: str, rcvbuf: int | None = None):
        self.url = url
        self.rcvbuf = rcvbuf
        self.ws = None
        self.server_info: dict = {}
        self.channels: dict[str, dict] = {}  # topic -> advertised channel
        self._sub_topic: dict[int, str] = {}
        self.messages: dict[str, list[tuple[float, int, bytes]]] = {}  # (wall, log ns, data)
        self._stores: dict[str, object] = {}
        self.times: list[tuple[float, int]] = []  # (wall, server time ns)
        self.states: list[dict] = []  # playback states received, with the wall time
        self.statuses: list[dict] = []  # status messages
        self.parameter_values: list[dict] = []  # parameterValues messages

    async def connect(self, timeout: float = 10.0) -> None:
        """Open the connection and wait for serverInfo and the advertised channels."""
        sock = None
        if self.rcvbuf is not None:  # a small receive window: a stall fills up quickly
            host, port = self.url.removeprefix("ws://").split(":")
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.rcvbuf)
            sock.connect((host, int(port)))
        self.ws = await websockets.connect(self.url, subprotocols=[SUBPROTOCOL], sock=sock,
                                           max_size=None, open_timeout=timeout)
        assert self.ws.subprotocol == SUBPROTOCOL
        deadline = time.monotonic() + timeout
        while not self.channels or not self.server_info:
            frame = await asyncio.wait_for(self.ws.recv(), max(0.1, deadline - time.monotonic()))
            self._handle(frame)

    async def subscribe(self, topics: list[str]) -> None:
        """Subscribe to ``topics`` (subscription ids chosen here)."""
        subs = []
        for topic in topics:
            sub_id = len(self._sub_topic) + 1
            self._sub_topic[sub_id] = topic
            self.messages.setdefault(topic, [])
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def read_for(self, seconds: float) -> None:
        """Receive and record frames for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = await asyncio.wait_for(self.ws.recv(), left)
            except TimeoutError:
                return
            self._handle(frame)

    async def close(self) -> None:
        """Close the connection (without waiting for a clean close from a stalled peer)."""
        if self.ws is not None:
            self.ws.transport.abort()

    async def send_json(self, **msg) -> None:
        """Send one JSON text frame."""
        await self.ws.send(json.dumps(msg))

    async def playback(self, command: str, speed: float, seek_ns: int | None = None,
                       request_id: str = "r") -> None:
        """Send a playback control request (``play`` or ``pause``)."""
        rid = request_id.encode()
        await self.ws.send(_CONTROL.pack(3, {"play": 0, "pause": 1}[command], speed,
                                         seek_ns is not None, seek_ns or 0, len(rid)) + rid)

    async def advertise(self, channel_id: int, topic: str, encoding: str, schema_name: str,
                        schema: str = "") -> None:
        """Advertise a client channel (clientPublish)."""
        channel = {"id": channel_id, "topic": topic, "encoding": encoding,
                   "schemaName": schema_name}
        if schema:  # required for cdr; a json channel may go without
            channel.update(schemaEncoding="ros2msg", schema=schema)
        await self.send_json(op="advertise", channels=[channel])

    async def publish(self, channel_id: int, payload: bytes) -> None:
        """Send one message on an advertised client channel."""
        await self.ws.send(struct.pack("<BI", 1, channel_id) + payload)

    async def wait_for(self, condition, timeout: float, what: str) -> None:
        """Receive frames until ``condition()`` holds."""
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, f"timed out waiting for {what}"
            await self.read_for(0.05)

    def _handle(self, frame) -> None:
        now = time.monotonic()
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                for channel in msg["channels"]:
                    self.channels[channel["topic"]] = channel
            elif msg["op"] == "status":
                self.statuses.append(msg)
            elif msg["op"] == "parameterValues":
                self.parameter_values.append(msg)
            return
        opcode = frame[0]
        if opcode == 2:
            self.times.append((now, _TIME.unpack_from(frame)[1]))
            return
        if opcode == 5:
            _, status, current, speed, did_seek, length = _STATE.unpack_from(frame)
            rid = bytes(frame[_STATE.size:_STATE.size + length]).decode()
            self.states.append({"wall": now, "status": PLAYBACK_STATUS[status],
                                "current_ns": current, "speed": speed,
                                "did_seek": bool(did_seek), "request_id": rid})
            return
        opcode, sub_id, log_ns = _HEADER.unpack_from(frame)
        assert opcode == 1, f"unexpected binary opcode {opcode}"
        topic = self._sub_topic[sub_id]
        self.messages[topic].append((now, log_ns, bytes(frame[_HEADER.size:])))

    def decode(self, topic: str, data: bytes):
        """Decode ``data`` with rosbags from the channel's advertised ros2msg schema."""
        channel = self.channels[topic]
        name = channel["schemaName"]
        store = self._stores.get(name)
        if store is None:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(channel["schema"], name))
            self._stores[name] = store
        return store.deserialize_cdr(data, name)

    def rate(self, topics: list[str], start: float, stop: float) -> float:
        """Messages per wall second received on ``topics`` in [start, stop)."""
        n = sum(1 for t in topics for wall, _, _ in self.messages[t] if start <= wall < stop)
        return n / (stop - start)
