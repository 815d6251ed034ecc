"""The Foxglove WebSocket server of the dashboard (foxglove-sdk), with its health figures.

:class:`DashboardServer` starts ``foxglove.start_server`` on its own ``foxglove.Context`` (so
several servers can live in one process) and creates one channel per
:data:`~clutch_ros.dashboard.topics.TOPICS` entry (``cdr`` payloads, ``ros2msg`` schemas, see
:mod:`~clutch_ros.dashboard.topics`). :meth:`DashboardServer.publish` hands the CDR bytes of
one message to the SDK, which sends them to every client subscribed to that channel (binary
frames: opcode 1, u32 subscription id, u64 log time [ns], payload; subprotocol
``foxglove.sdk.v1``).

Slow clients (what foxglove-sdk 0.30 does, read in its source, ``rust/foxglove/src/websocket/
connected_client``): every client has its own bounded outgoing queue of
``message_backlog_size`` messages (``backlog`` here); a log call only *tries* to enqueue and,
when the queue is full, drops that client's oldest queued message to make room. Logging never
blocks, so a stalled client slows neither the publisher nor the other clients, and its memory
stays bounded. The SDK does not return the number of messages it dropped (its ``SentLossy``
count is discarded); what it does expose is a log record ``outbox for client ADDR full``
(logger ``foxglove.websocket.connected_client.send_lossy``, at most one per 30 s per process).
The server counts those overflow events per client address, and counts client connections
from the SDK's ``Registered client`` / ``Unregistered client`` records; :meth:`status` reports
them with the messages forwarded per topic, for ``/diagnostics``.

Capabilities (serverInfo): ``time`` on request (:meth:`DashboardServer.broadcast_time`),
``parameters``, ``clientPublish`` and ``playbackControl`` when given their handlers
(:mod:`~clutch_ros.dashboard.sdk_listener`). The SDK accepts only clients that offer the
WebSocket subprotocol ``foxglove.sdk.v1``; any other (an app speaking only the older
``foxglove.websocket.v1``) gets HTTP 400 "Missing expected sec-websocket-protocol header".
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.sdk_listener import (
    ParameterHandler,
    PlaybackHandler,
    PlaybackReport,
    SdkListener,
    sdk_playback_state,
    to_sdk_parameters,
)
from clutch_ros.dashboard.topics import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    TOPICS,
    DashboardTopic,
    message_definition,
)

if TYPE_CHECKING:
    from foxglove.websocket import WebSocketServer

__all__ = ["DEFAULT_BACKLOG", "DEFAULT_HOST", "DEFAULT_PORT", "DashboardServer", "absolute"]

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
#: Messages queued per client before the oldest is dropped (the SDK's default is 1024).
DEFAULT_BACKLOG = 1024

_OVERFLOW_LOGGER = "foxglove.websocket.connected_client.send_lossy"
_SERVER_LOGGER = "foxglove.websocket.server"
_OVERFLOW = re.compile(r"outbox for client (\S+) full")
_REGISTERED = re.compile(r"^(Registered|Unregistered) client (\S+)")


def absolute(name: str, namespace: str = "/") -> str:
    """Return the absolute topic name: ``rig_state`` in ``/rig1`` -> ``/rig1/rig_state``."""
    if name.startswith("/"):
        return name
    ns = namespace.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


class _SdkLogTap(logging.Handler):
    """Count the SDK's overflow and client (un)registration log records."""

    def __init__(self, owner: DashboardServer):
        super().__init__(level=logging.INFO)
        self._owner = owner

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._owner._on_sdk_log(record.getMessage())
        except Exception:  # noqa: BLE001 - a log handler must never raise into the SDK
            self.handleError(record)


class DashboardServer:
    """Foxglove WebSocket server with one ``cdr``/``ros2msg`` channel per dashboard topic.

    Args:
        host: bind address (default ``127.0.0.1``: this machine only; ``0.0.0.0`` for all).
        port: TCP port (default 8765; 0 picks a free one, see :attr:`port`).
        backlog: messages queued per client before its oldest are dropped [messages].
        topics: the topics to serve (default :data:`~clutch_ros.dashboard.topics.TOPICS`).
        namespace: ROS namespace that relative topic names resolve in (default ``/``).
        name: server name shown by Foxglove.
        serve_time: advertise ``Capability.Time``; the owner calls :meth:`broadcast_time` with the
            time its log times come from (bag time, or the node clock).
        playback_range: ``(start_ns, end_ns)`` of the data played back [ns since epoch]:
            advertises playback control (``dataStartTime``/``dataEndTime`` in serverInfo);
            needs ``playback``.
        playback: the :class:`~clutch_ros.dashboard.sdk_listener.PlaybackHandler`.
        parameters: a :class:`~clutch_ros.dashboard.sdk_listener.ParameterHandler`:
            advertises ``parameters`` (and ``parametersSubscribe``).
        publish: a :class:`~clutch_ros.dashboard.client_publish.PublishGate`: advertises
            ``clientPublish`` with its encodings (``cdr``, ``json``).

    Raises:
        DashboardError: the server cannot listen on ``host:port`` or ``backlog`` < 1.

    Use as a context manager or call :meth:`close`.
    """

    _server: WebSocketServer | None  # None once closed

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        *,
        backlog: int = DEFAULT_BACKLOG,
        topics: Iterable[DashboardTopic] = TOPICS,
        namespace: str = "/",
        name: str = "clutch_ros dashboard",
        serve_time: bool = False,
        playback_range: tuple[int, int] | None = None,
        playback: PlaybackHandler | None = None,
        parameters: ParameterHandler | None = None,
        publish: Any = None,
    ):
        import foxglove  # loads the SDK's native server: only when a dashboard is served

        if int(backlog) < 1:
            raise DashboardError(f"message backlog must be >= 1 message, not {backlog}")
        if not 0 <= int(port) <= 65535:
            raise DashboardError(f"port {port} is not a TCP port (0..65535)")
        self.backlog = int(backlog)
        self._lock = threading.Lock()
        self._forwarded: dict[str, int] = {}
        self._subscriptions: dict[int, set[str]] = {}
        self._clients: set[str] = set()
        self._connections = 0
        self._overflows: dict[str, int] = {}
        self._statuses = 0
        self._tap = _SdkLogTap(self)
        self._attach_tap()
        self._context = foxglove.Context()
        self.channels: dict[str, Any] = {}
        self.typenames: dict[str, str] = {}
        for topic in topics:
            abs_name = absolute(topic.name, namespace)
            self.channels[abs_name] = foxglove.Channel(
                abs_name,
                schema=foxglove.Schema(
                    name=topic.typename,
                    encoding=SCHEMA_ENCODING,
                    data=message_definition(topic.typename).encode("utf-8"),
                ),
                message_encoding=MESSAGE_ENCODING,
                context=self._context,
            )
            self.typenames[abs_name] = topic.typename
            self._forwarded[abs_name] = 0
        from foxglove.websocket import Capability

        capabilities = [Capability.Time] if serve_time else []
        if parameters is not None:
            capabilities.append(Capability.Parameters)
        if publish is not None:
            capabilities.append(Capability.ClientPublish)
        if playback_range is not None:
            if playback is None:
                raise DashboardError("playback control needs a playback handler")
            capabilities.append(Capability.PlaybackControl)
        self.listener = SdkListener(self, parameters, publish, playback)
        try:
            self._server = foxglove.start_server(
                name=name,
                host=host,
                port=int(port),
                context=self._context,
                # SdkListener has every callback of the SDK's ServerListener Protocol; it does
                # not subclass it, which would load the native SDK on import
                server_listener=self.listener,
                message_backlog_size=self.backlog,
                capabilities=capabilities,
                supported_encodings=list(publish.encodings) if publish is not None else None,
                playback_time_range=(None if playback_range is None else
                                     (int(playback_range[0]), int(playback_range[1]))),
            )
        except Exception as err:  # noqa: BLE001 - the SDK raises its own error types
            self._detach_tap()
            raise DashboardError(f"cannot serve on {host}:{port}: {err}") from err
        self.host = host
        self.started = time.monotonic()

    # -- lifecycle ---------------------------------------------------------------------------
    @property
    def port(self) -> int:
        """The TCP port the server listens on (the chosen one when started with port 0)."""
        server = self._server
        if server is None:
            raise DashboardError("the dashboard server is closed")
        return int(server.port)

    @property
    def url(self) -> str:
        """``ws://HOST:PORT`` to open in Foxglove (``localhost`` for a wildcard bind)."""
        host = "localhost" if self.host in ("0.0.0.0", "::", "") else self.host
        return f"ws://{host}:{self.port}"

    def close(self) -> None:
        """Stop the server (clients are disconnected) and close the channels."""
        server, self._server = getattr(self, "_server", None), None
        if server is not None:
            server.stop()
            for channel in self.channels.values():
                channel.close()
        self._detach_tap()

    def __enter__(self) -> DashboardServer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- data --------------------------------------------------------------------------------
    def publish(self, topic: str, data: bytes, log_time_ns: int | None = None) -> None:
        """Send one CDR-encoded message on ``topic`` to its subscribed clients; never blocks.

        Args:
            topic: absolute topic name (a key of :attr:`channels`).
            data: the serialized message, CDR with its 4-byte encapsulation header.
            log_time_ns: the message's log time [ns since epoch] (default: now).

        Raises:
            DashboardError: ``topic`` is not served.

        """
        channel = self.channels.get(topic)
        if channel is None:
            raise DashboardError(f"topic {topic} is not served (served: "
                                 f"{', '.join(self.channels)})")
        channel.log(bytes(data), log_time=time.time_ns() if log_time_ns is None else log_time_ns)
        self._forwarded[topic] += 1

    def broadcast_time(self, time_ns: int) -> None:
        """Send the server's time [ns since epoch] to every client (``time`` capability)."""
        server = self._server
        if server is not None and time_ns > 0:
            server.broadcast_time(int(time_ns))

    def broadcast_playback(self, report: PlaybackReport) -> None:
        """Send the player's state to every client (not in answer to a request)."""
        server = self._server
        if server is not None:
            server.broadcast_playback_state(sdk_playback_state(report))

    def publish_parameters(self, values: dict[str, Any]) -> None:
        """Send changed parameter values to the clients subscribed to them."""
        server = self._server
        if server is not None and values:
            server.publish_parameter_values(to_sdk_parameters(values))

    def status_message(self, text: str, level: str = "info", status_id: str | None = None
                       ) -> None:
        """Show ``text`` in every client (``level``: info, warning, error).

        A later message with the same ``status_id`` replaces it.
        """
        from foxglove import StatusLevel

        server = self._server
        if server is None:
            return
        levels = {"info": StatusLevel.Info, "warning": StatusLevel.Warning,
                  "error": StatusLevel.Error}
        with self._lock:
            self._statuses += 1
        server.publish_status(text, levels[level], status_id)

    def has_subscribers(self, topic: str) -> bool:
        """Return True when at least one client is subscribed to ``topic``."""
        channel = self.channels.get(topic)
        return channel is not None and channel.has_sinks()

    # -- health ------------------------------------------------------------------------------
    def status(self) -> tuple[str, str, dict[str, Any]]:
        """Return ``(level, message, values)`` for ``/diagnostics``.

        Values: ``url``, ``clients`` (connected now), ``connections`` (since start),
        ``subscriptions``, ``message_backlog`` [messages per client], ``forwarded_<topic>``
        [messages], ``outbox_full_events`` (SDK overflow reports: each means that client's
        oldest queued messages were dropped), ``outbox_full_clients`` (their addresses).
        Level ``WARN`` once a client's queue overflowed.
        """
        with self._lock:
            values: dict[str, Any] = {
                "url": self.url,
                "clients": len(self._clients),
                "connections": self._connections,
                "subscriptions": sum(len(s) for s in self._subscriptions.values()),
                "message_backlog": self.backlog,
                "status_messages": self._statuses,
            }
            overflows = dict(self._overflows)
        for topic, count in self._forwarded.items():
            values[f"forwarded_{topic.strip('/').replace('/', '_')}"] = count
        values["outbox_full_events"] = sum(overflows.values())
        values["outbox_full_clients"] = " ".join(sorted(overflows)) or "none"
        if overflows:
            return ("WARN", f"{len(overflows)} slow client(s) lost their oldest queued messages "
                    f"(queue {self.backlog} messages)", values)
        return "OK", f"serving {values['clients']} client(s) on {self.url}", values

    def _on_subscription(self, client_id: int, topic: str, delta: int) -> None:
        with self._lock:
            subs = self._subscriptions.setdefault(client_id, set())
            if delta > 0:
                subs.add(topic)
            else:
                subs.discard(topic)
                if not subs:
                    del self._subscriptions[client_id]

    def _on_sdk_log(self, text: str) -> None:
        match = _OVERFLOW.search(text)
        with self._lock:
            if match:
                addr = match.group(1)
                self._overflows[addr] = self._overflows.get(addr, 0) + 1
                return
            match = _REGISTERED.search(text)
            if match and match.group(1) == "Registered":
                self._clients.add(match.group(2))
                self._connections += 1
            elif match:
                self._clients.discard(match.group(2))

    def _attach_tap(self) -> None:
        for name in (_OVERFLOW_LOGGER, _SERVER_LOGGER):
            logger = logging.getLogger(name)
            if logger.getEffectiveLevel() > logging.INFO:
                logger.setLevel(logging.INFO)
            logger.addHandler(self._tap)

    def _detach_tap(self) -> None:
        for name in (_OVERFLOW_LOGGER, _SERVER_LOGGER):
            logging.getLogger(name).removeHandler(self._tap)
