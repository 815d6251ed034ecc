"""A minimal Foxglove WebSocket client (``websockets``), speaking the protocol itself.

Independent of foxglove-sdk on purpose: it checks what goes over the wire. JSON text frames:
``serverInfo``, ``advertise`` (channels with ``encoding``, ``schemaName``, ``schemaEncoding``,
``schema``), ``subscribe``; binary server frames: opcode 1 (message data), u32 subscription
id, u64 log time [ns], payload (little endian).
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

    def _handle(self, frame) -> None:
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                self.server_info = msg
            elif msg["op"] == "advertise":
                for channel in msg["channels"]:
                    self.channels[channel["topic"]] = channel
            return
        opcode, sub_id, log_ns = _HEADER.unpack_from(frame)
        assert opcode == 1, f"unexpected binary opcode {opcode}"
        topic = self._sub_topic[sub_id]
        self.messages[topic].append((time.monotonic(), log_ns, bytes(frame[_HEADER.size:])))

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
