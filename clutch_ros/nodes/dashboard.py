"""The ``dashboard`` node: the clutch topics live on a Foxglove WebSocket server.

Subscribes to ``rig_state`` (sensor-data QoS: best effort), ``clutch_estimate``,
``torque_request``, ``pressure_command``, ``pump_request`` and ``/diagnostics`` (reliable)
*raw*, and forwards the serialized CDR bytes ROS delivers, unchanged, to the Foxglove channels
of a :class:`clutch_ros.dashboard.DashboardServer` (``cdr`` payloads with ``ros2msg`` schemas;
log time = node clock at receipt). In Foxglove: open connection -> Foxglove WebSocket ->
``ws://HOST:PORT`` (README.md). Clients may come and go at any time; a slow client never
slows the node or the other clients (each client has a bounded queue of
``dashboard.message_backlog`` messages, its oldest messages are dropped when it is full).
``/diagnostics`` reports clients, subscriptions, messages forwarded per topic, samples lost
before the node (DDS sequence gaps) and the SDK's reports of clients whose queue overflowed.
"""

from __future__ import annotations

import importlib

from rclpy.node import Node

from clutch_ros.config.presets import LAYOUT_NAME, share_file
from clutch_ros.dashboard import TOPICS, DashboardServer, absolute
from clutch_ros.errors import ConfigError
from clutch_ros.nodes.diagnostics import Diagnostics
from clutch_ros.nodes.loss_tracker import LossTracker
from clutch_ros.nodes.parameters import ParamSpec, declare_params
from clutch_ros.nodes.qos import reliable_qos, sensor_qos
from clutch_ros.nodes.runner import run_node

NAME = "dashboard"
PARAMS = [
    ParamSpec("dashboard.port", 8765, "TCP port of the Foxglove WebSocket server (0: any free "
              "port, logged at start)", "", 0, 65535, read_only=True),
    ParamSpec("dashboard.address", "127.0.0.1", "bind address of the server (127.0.0.1: this "
              "machine only; 0.0.0.0: every interface)", read_only=True),
    ParamSpec("dashboard.message_backlog", 1024, "messages queued per client before its oldest "
              "are dropped", "messages", 1, 1000000, read_only=True),
    ParamSpec("dashboard.queue_depth", 200, "subscription queue of each topic", "messages", 1,
              100000, read_only=True),
]


class DashboardNode(Node):
    """Foxglove WebSocket server of the clutch topics (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        cfg = declare_params(self, PARAMS)
        namespace = self.get_namespace()
        self._server = DashboardServer(cfg["dashboard.address"], cfg["dashboard.port"],
                                       backlog=cfg["dashboard.message_backlog"],
                                       namespace=namespace)
        self._loss = LossTracker()
        for topic in TOPICS:
            name = absolute(topic.name, namespace)
            self._loss.add_topic(name)
            qos = sensor_qos() if topic.sensor_data else reliable_qos(
                cfg["dashboard.queue_depth"])
            self.create_subscription(_msg_class(topic.typename), topic.name,
                                     self._forwarder(name), qos, raw=True)
        self._diag = Diagnostics(self, self._diagnose)
        self.get_logger().info(f"Foxglove WebSocket server on {self._server.url} "
                               f"({len(TOPICS)} channels){_layout_hint()}")

    def _forwarder(self, topic: str):
        publish = self._server.publish
        clock = self.get_clock()
        loss = self._loss

        def forward(data: bytes, info=None) -> None:
            loss.received(topic, info)
            publish(topic, data, clock.now().nanoseconds)

        return forward

    def _diagnose(self):
        level, message, values = self._server.status()
        for topic, stats in self._loss.topics.items():
            values[f"lost_{topic.strip('/').replace('/', '_')}"] = stats.dropped
        return level, message, values

    def close(self) -> None:
        """Stop the server (called by run_node at shutdown)."""
        self._server.close()


def _layout_hint() -> str:
    """Return "; layout PATH" of the shipped Foxglove layout, "" when the share is not found."""
    try:
        return f"; layout {share_file(LAYOUT_NAME)}"
    except ConfigError:
        return ""


def _msg_class(typename: str):
    """Return the rclpy message class of ``pkg/msg/Type``."""
    package, _, name = typename.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros dashboard``."""
    return run_node(NAME, __doc__, PARAMS, DashboardNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
