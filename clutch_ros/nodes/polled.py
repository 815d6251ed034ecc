"""Subscriptions the executor does not wait on: a timer's callback takes their messages.

Why: every message of an ordinary subscription wakes the node's executor, and one wake-up (the
wait set of the node's services, subscriptions, timers and QoS event handlers filled and
waited on, the ready entities read back, the message taken) costs ~0.3-0.5 ms of CPU with
the lean executor (``python -m benchmarks.wakeup_probe``). The controller at the demo's rates
took four inputs of ~100 messages/s each (``torque_request``, ``rig_state``,
``clutch_estimate``, its 100 Hz timer), yet it only needs their newest values when its timer
computes a command. A :class:`PolledSubscription` is a real subscription of the node (in the
ROS graph with its QoS, matched and delivered as any other; the middleware queues what
arrives, up to the QoS depth) that no executor waits on: :meth:`PolledSubscription.take`
returns what is queued, when the node asks.

What a polled input gives up: the middleware's QoS event callbacks (incompatible-QoS
warnings) and delivery at arrival; what arrives between two polls waits until the next one
(its arrival time is kept: :attr:`Taken.received`). Messages beyond the QoS depth between two
polls are dropped by the middleware, oldest first, as for a subscription whose callbacks run
late.

The handle comes from rclpy's C extension (as rclpy's own ``Node.create_subscription`` makes
it, and as :mod:`clutch_ros.nodes.lean_executor` uses it); :meth:`PolledSubscription.destroy`
frees it (the node calls it from its ``destroy_node``).
"""

from __future__ import annotations

from collections import namedtuple
from typing import Any, NamedTuple

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.type_support import check_is_valid_msg_type

from clutch_ros.nodes.convert import CdrCodec

__all__ = ["PolledSubscription", "Taken"]


class Taken(NamedTuple):
    """One message taken from a :class:`PolledSubscription`.

    ``message``: the message (bytes for a ``raw`` subscription); ``received``: the
    middleware's reception time [s] (system clock: ROS time without ``use_sim_time``), or None
    when the middleware gives none; ``info``: the whole message info (rclpy's dict:
    ``publisher_gid``, ``publication_sequence_number``, ...).
    """

    message: Any
    received: float | None
    info: Any = None


class PolledSubscription:
    """A subscription of ``node`` to ``topic`` that no executor waits on (module docstring).

    ``msg_type``: the message class; ``qos``: its :class:`~rclpy.qos.QoSProfile`; ``raw``:
    take serialized bytes (:meth:`take` and :meth:`take_newest` then return bytes).
    """

    def __init__(self, node, msg_type, topic: str, qos: QoSProfile, raw: bool = False) -> None:
        self.msg_type, self.raw = msg_type, raw
        check_is_valid_msg_type(msg_type)  # (also loads the type support, as rclpy does)
        with node.handle:
            self._handle: Any = _rclpy.Subscription(node.handle, msg_type, topic,
                                                    qos.get_c_qos_profile(), None)
        #: messages taken since the start
        self.taken = 0
        self._codec: CdrCodec | None = None  # (raw: made by the first view())
        self._view: Any = None

    @property
    def topic_name(self) -> str:
        """The fully resolved topic name."""
        with self._handle:
            return self._handle.get_topic_name()

    def take(self) -> list[Taken]:
        """Return every message queued now, oldest first (may be empty)."""
        out: list[Taken] = []
        handle, msg_type, raw = self._handle, self.msg_type, self.raw
        with handle:
            while (item := handle.take_message(msg_type, raw)) is not None:
                received = item[1].get("received_timestamp", 0)
                out.append(Taken(item[0], received * 1e-9 if received > 0 else None, item[1]))
        self.taken += len(out)
        return out

    def take_newest(self) -> Taken | None:
        """Return the newest queued message (older ones are discarded), or None.

        A ``raw`` subscription's older messages are skipped as bytes; with ``decode`` the
        newest is deserialised into ``msg_type`` once.
        """
        items = self.take()
        return items[-1] if items else None

    def decode(self, data: bytes):
        """Deserialise ``data`` (a raw message of this subscription) into ``msg_type``."""
        return deserialize_message(data, self.msg_type)

    def view(self, data: bytes):
        """Return the fields of ``data`` (a raw message) as a named tuple, without a message.

        Nested fields are flattened with ``_`` (``header_stamp_sec``); read from the CDR bytes
        by :class:`~clutch_ros.nodes.convert.CdrCodec` (a few us, where rclpy's
        deserialisation into a message object cost ~0.1 ms for a ``ClutchEstimate`` in the
        controller process); the values are the message's.
        """
        if self._codec is None:
            self._codec = CdrCodec(self.msg_type)
            self._view = namedtuple(f"{self.msg_type.__name__}View",  # type: ignore[misc]
                                    [n.replace(".", "_") for n in self._codec.names])
        return self._view._make(self._codec.decode(data))

    def destroy(self) -> None:
        """Free the subscription (once it is not in use); :meth:`take` must not follow."""
        self._handle.destroy_when_not_in_use()
