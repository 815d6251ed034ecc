"""The foxglove-sdk ``ServerListener`` of the dashboard: what clients ask, handed to handlers.

The SDK calls these methods on its own threads (one per client request), holding the GIL
only while Python runs. Each capability is served by a plain-Python handler the owner of the
:class:`~clutch_ros.dashboard.server.DashboardServer` supplies, so the handlers know nothing
of the SDK's types:

- parameters (``Capability.Parameters``): a :class:`ParameterHandler`; values are Python
  ``bool``/``int``/``float``/``str``/lists. Each refusal it reports reaches the clients as a
  warning status message with the reason.
- client publish (``Capability.ClientPublish``): a
  :class:`~clutch_ros.dashboard.client_publish.PublishGate`-like object; a refused
  advertisement or message becomes a warning status message.
- playback control (``Capability.PlaybackControl``): a :class:`PlaybackHandler`, whose answer
  the SDK sends back as the ``playbackState`` of the request.

The status messages go to every connected client (the SDK's Python API has no per-client
status), with an id per subject so a later one replaces it.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Protocol

from clutch_ros.errors import ClutchError

__all__ = ["ParameterHandler", "PlaybackHandler", "PlaybackReport", "SdkListener",
           "to_sdk_parameters"]


class PlaybackReport(NamedTuple):
    """The player's state.

    ``status`` (``playing``, ``paused``, ``ended``), ``current_ns`` (bag time [ns since
    epoch]), ``speed`` (× real time), ``did_seek`` (this change was a seek).
    """

    status: str
    current_ns: int
    speed: float
    did_seek: bool = False


class ParameterHandler(Protocol):
    """Parameters by their full name (``/estimator.spline.law``)."""

    def get(self, names: list[str]) -> dict[str, Any]:
        """Return name -> value for ``names`` (empty: every parameter)."""
        ...

    def set(self, changes: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
        """Apply ``changes``; return the values now in force and one reason per refusal."""
        ...


class PlaybackHandler(Protocol):
    """Playback control: a client's request, answered with the state that follows."""

    def request(self, play: bool, speed: float, seek_ns: int | None) -> PlaybackReport:
        """Play or pause at ``speed`` (× real time), after seeking to ``seek_ns`` if given."""
        ...


def _sdk_parameter(name: str, value: Any) -> Any:
    import foxglove  # the native SDK: only where a server runs

    kind = foxglove.ParameterType
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, float):
        return foxglove.Parameter(name, value=value, type=kind.Float64)
    if (isinstance(value, list) and value and all(isinstance(v, float) for v in value)):
        return foxglove.Parameter(name, value=value, type=kind.Float64Array)
    if isinstance(value, bytes):
        return foxglove.Parameter(name, value=value, type=kind.ByteArray)
    return foxglove.Parameter(name, value=value)


def to_sdk_parameters(values: dict[str, Any]) -> list[Any]:
    """Return foxglove ``Parameter`` objects of ``values`` (floats typed ``Float64``)."""
    return [_sdk_parameter(name, value) for name, value in values.items() if value is not None]


def _native(parameter: Any) -> Any:
    """Return a client's parameter value as Python (a float the client typed stays one)."""
    import foxglove

    value = parameter.get_value()
    if parameter.type == foxglove.ParameterType.Float64 and isinstance(value, int):
        return float(value)
    return value


class SdkListener:
    """foxglove ``ServerListener``: subscriptions to the owner, requests to the handlers.

    Args:
        owner: the server (``_on_subscription``, ``status_message``, ``broadcast``).
        parameters: a :class:`ParameterHandler` or None.
        publish: the client-publish gate or None.
        playback: a :class:`PlaybackHandler` or None.

    """

    def __init__(self, owner: Any, parameters: ParameterHandler | None = None,
                 publish: Any = None, playback: PlaybackHandler | None = None):
        self._owner = owner
        self.parameters = parameters
        self.publish = publish
        self.playback = playback

    # -- channels ---------------------------------------------------------------------------
    def on_subscribe(self, client: Any, channel: Any) -> None:
        """Count a subscription."""
        self._owner._on_subscription(client.id, channel.topic, +1)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """Count an unsubscription."""
        self._owner._on_subscription(client.id, channel.topic, -1)

    # -- parameters -------------------------------------------------------------------------
    def on_get_parameters(self, client: Any, param_names: list[str],
                          request_id: str | None = None) -> list[Any]:
        """Answer getParameters (empty names: all)."""
        if self.parameters is None:
            return []
        try:
            values = self.parameters.get(list(param_names))
        except ClutchError as err:
            self._owner.status_message(f"get parameters: {err}", "warning", "parameters")
            return []
        return to_sdk_parameters(values)

    def on_set_parameters(self, client: Any, parameters: list[Any],
                          request_id: str | None = None) -> list[Any]:
        """Answer setParameters: the values in force; refusals as status messages."""
        if self.parameters is None:
            return []
        changes = {p.name: _native(p) for p in parameters}
        try:
            values, refusals = self.parameters.set(changes)
        except ClutchError as err:
            values, refusals = {}, [f"set parameters {', '.join(changes)}: {err}"]
        for reason in refusals:
            self._owner.status_message(reason, "warning", "parameters")
        return to_sdk_parameters(values)

    def on_parameters_subscribe(self, param_names: list[str]) -> None:
        """Nothing to do: changes come from the handler's owner."""
        return None

    def on_parameters_unsubscribe(self, param_names: list[str]) -> None:
        """Nothing to do."""
        return None

    # -- client publish ---------------------------------------------------------------------
    def on_client_advertise(self, client: Any, channel: Any) -> None:
        """Admit or refuse a client channel."""
        if self.publish is None:
            return
        refusal = self.publish.advertise(client.id, channel.id, channel.topic, channel.encoding,
                                         channel.schema_name)
        if refusal:
            self._owner.status_message(refusal, "warning", f"publish:{channel.topic}")

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        """Forget a client channel."""
        if self.publish is not None:
            self.publish.unadvertise(client.id, client_channel_id)

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        """Pass a client message on, or refuse it."""
        if self.publish is None:
            return
        refusal = self.publish.message(client.id, client_channel_id, bytes(data))
        if refusal:
            self._owner.status_message(refusal, "warning", "publish")

    # -- the rest of the protocol -----------------------------------------------------------
    def on_connection_graph_subscribe(self) -> None:
        """Not offered."""
        return None

    def on_connection_graph_unsubscribe(self) -> None:
        """Not offered."""
        return None

    def on_playback_control_request(self, playback_control_request: Any) -> Any:
        """Answer a playback-control request with the state that follows."""
        from foxglove.websocket import PlaybackCommand

        if self.playback is None:
            return None
        req = playback_control_request
        speed = float(req.playback_speed)
        report = self.playback.request(req.playback_command == PlaybackCommand.Play,
                                       speed if math.isfinite(speed) else 0.0, req.seek_time)
        return sdk_playback_state(report, req.request_id)


def sdk_playback_state(report: PlaybackReport, request_id: str | None = None) -> Any:
    """Return the SDK's ``PlaybackState`` of ``report``."""
    from foxglove.websocket import PlaybackState, PlaybackStatus

    status = {"playing": PlaybackStatus.Playing, "paused": PlaybackStatus.Paused,
              "ended": PlaybackStatus.Ended}[report.status]
    return PlaybackState(status=status, current_time=int(report.current_ns),
                         playback_speed=float(report.speed), did_seek=bool(report.did_seek),
                         request_id=request_id)

