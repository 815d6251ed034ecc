"""Client publishing, gated: which topic a client may publish on, decoded to a request.

The dashboard's ``clientPublish`` capability (off unless ``dashboard.allow_publish``) admits
one topic, ``torque_request`` (``clutch_msgs/msg/TorqueRequest``), a whitelist. A client
advertises a channel (topic, encoding ``cdr`` or ``json``, schema name) and then sends
messages on it. :class:`PublishGate` answers each advertisement and message with None
(accepted) or the reason of the refusal, which the server shows the clients as a status
message; accepted messages are decoded to ``(stamp_ns or None, frame_id, torque)`` and handed
to the sink (the node publishes them to ROS, stamped on arrival when the client left the
stamp at zero). The controller's own admission and limits then apply as to any request.

Payloads: ``cdr`` is the ROS 2 serialization (what Foxglove's Publish panel sends to a ROS 2
server); ``json`` is ``{"header": {"stamp": {"sec": S, "nanosec": N}, "frame_id": F},
"torque": T}`` with the header optional (``nsec`` is read as ``nanosec``).
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable
from typing import Any

from clutch_ros import interfaces
from clutch_ros.bag.typestore import clutch_typestore
from clutch_ros.dashboard.server import absolute

__all__ = ["ENCODINGS", "PublishGate", "decode_torque_request"]

#: Message encodings a client may publish in.
ENCODINGS = ("cdr", "json")
_TYPENAME = interfaces.TORQUE_REQUEST.typename


def decode_torque_request(encoding: str, data: bytes) -> tuple[int | None, str, float]:
    """Return ``(stamp_ns or None when zero, frame_id, torque [N m])`` of one payload.

    Raises:
        ValueError: the payload is not a TorqueRequest in ``encoding``.

    """
    if encoding == "cdr":
        try:
            msg: Any = clutch_typestore().deserialize_cdr(data, _TYPENAME)
        except Exception as err:  # noqa: BLE001 - rosbags raises several kinds
            raise ValueError(f"not a CDR {_TYPENAME}: {err}") from err
        sec, nanosec = msg.header.stamp.sec, msg.header.stamp.nanosec
        frame_id, torque = msg.header.frame_id, msg.torque
    else:
        try:
            obj = json.loads(data)
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ValueError(f"not JSON: {err}") from err
        if not isinstance(obj, dict) or "torque" not in obj:
            raise ValueError('a JSON TorqueRequest is an object with "torque" [N m]')
        header = obj.get("header") or {}
        stamp = header.get("stamp") or {}
        sec, nanosec = stamp.get("sec", 0), stamp.get("nanosec", stamp.get("nsec", 0))
        frame_id, torque = header.get("frame_id", ""), obj["torque"]
        if not (isinstance(sec, int) and isinstance(nanosec, int) and isinstance(frame_id, str)):
            raise ValueError("header.stamp.sec/nanosec must be integers, frame_id a string")
    if isinstance(torque, bool) or not isinstance(torque, (int, float)):
        raise ValueError(f"torque must be a number [N m], not {torque!r}")
    stamp_ns = int(sec) * 1_000_000_000 + int(nanosec)
    return (stamp_ns or None), frame_id, float(torque)


class PublishGate:
    """Admit client channels on the whitelisted topic only; decode their messages.

    Args:
        sink: called with ``(stamp_ns or None, frame_id, torque)`` per accepted message.
        namespace: ROS namespace ``torque_request`` resolves in.

    Attributes:
        topic: the one topic clients may publish on (``/torque_request``).
        encodings: the message encodings accepted (:data:`ENCODINGS`).
        accepted, refused: messages passed on and refused (with refused advertisements).

    """

    encodings = ENCODINGS

    def __init__(self, sink: Callable[[int | None, str, float], None], namespace: str = "/"):
        self._sink = sink
        self.topic = absolute(interfaces.TORQUE_REQUEST.name, namespace)
        self._channels: dict[tuple[int, int], str] = {}
        self._lock = threading.Lock()
        self.accepted = 0
        self.refused = 0

    def advertise(self, client_id: int, channel_id: int, topic: str, encoding: str,
                  schema_name: str) -> str | None:
        """Admit a client channel; return None or why it is refused."""
        reason = None
        if topic != self.topic:
            reason = (f"publishing on {topic} refused: clients may publish on {self.topic} "
                      f"({_TYPENAME}) only")
        elif encoding not in ENCODINGS:
            reason = (f"publishing on {topic} refused: encoding {encoding!r} is not one of "
                      f"{', '.join(ENCODINGS)}")
        elif schema_name not in (_TYPENAME, _TYPENAME.replace("/msg/", "/")):
            reason = (f"publishing on {topic} refused: schema {schema_name!r} is not "
                      f"{_TYPENAME}")
        with self._lock:
            if reason is None:
                self._channels[(client_id, channel_id)] = encoding
            else:
                self.refused += 1
        return reason

    def unadvertise(self, client_id: int, channel_id: int) -> None:
        """Forget a client channel."""
        with self._lock:
            self._channels.pop((client_id, channel_id), None)

    def message(self, client_id: int, channel_id: int, data: bytes) -> str | None:
        """Pass one client message on; return None or why it is refused."""
        with self._lock:
            encoding = self._channels.get((client_id, channel_id))
            if encoding is None:
                self.refused += 1
                return (f"message on client channel {channel_id} refused: the channel was "
                        f"refused (clients may publish on {self.topic} only)")
        try:
            stamp_ns, frame_id, torque = decode_torque_request(encoding, data)
        except ValueError as err:
            with self._lock:
                self.refused += 1
            return f"message on {self.topic} refused: {err}"
        if not math.isfinite(torque):
            with self._lock:
                self.refused += 1
            return f"message on {self.topic} refused: torque {torque} is not finite"
        self._sink(stamp_ns, frame_id, torque)
        with self._lock:
            self.accepted += 1
        return None

    def status(self) -> dict[str, Any]:
        """Return the counts for ``/diagnostics``."""
        with self._lock:
            return {"client_publish_accepted": self.accepted,
                    "client_publish_refused": self.refused}
