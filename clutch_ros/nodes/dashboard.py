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

Capabilities: ``time`` (the node clock every ``dashboard.time_period``: sim time under
``use_sim_time``, as the log times), ``parameters`` (the clutch nodes' parameters through
their parameter services, :mod:`clutch_ros.nodes.dashboard_params`; a refusal reaches the
clients as a status message with the node's reason) and, with ``dashboard.allow_publish``,
``clientPublish`` on ``torque_request`` only (:mod:`clutch_ros.dashboard.client_publish`),
stamped with the node clock on arrival when unstamped.
"""

from __future__ import annotations

import importlib

from clutch_msgs.msg import TorqueRequest
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from clutch_ros.config.presets import LAYOUT_NAME, share_file
from clutch_ros.dashboard import TOPICS, DashboardServer, absolute
from clutch_ros.dashboard.client_publish import PublishGate
from clutch_ros.errors import ConfigError
from clutch_ros.nodes.dashboard_params import RosParameters
from clutch_ros.nodes.diagnostics import Diagnostics
from clutch_ros.nodes.loss_tracker import LossTracker
from clutch_ros.nodes.parameters import ParamSpec, declare_params
from clutch_ros.nodes.qos import publisher_qos, reliable_qos, sensor_qos
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
    ParamSpec("dashboard.allow_publish", False, "let clients publish TorqueRequest on "
              "torque_request (the only topic they may publish on; the controller's limits "
              "apply)", read_only=True),
    ParamSpec("dashboard.time_period", 0.05, "period of the server's time messages (the node "
              "clock; sim time under use_sim_time)", "s", 0.01, 1.0, read_only=True),
    ParamSpec("dashboard.parameter_timeout", 2.0, "wait for a node's parameter service "
              "answer", "s", 0.1, 30.0, read_only=True),
]


class DashboardNode(Node):
    """Foxglove WebSocket server of the clutch topics (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        cfg = declare_params(self, PARAMS)
        namespace = self.get_namespace()
        self._gate = None
        if cfg["dashboard.allow_publish"]:
            self._requests = self.create_publisher(TorqueRequest, "torque_request",
                                                   publisher_qos("torque_request"))
            self._gate = PublishGate(self._publish_request, namespace)
        self._params = RosParameters(self, self._on_parameter_change,
                                     timeout=cfg["dashboard.parameter_timeout"])
        self._server = DashboardServer(cfg["dashboard.address"], cfg["dashboard.port"],
                                       backlog=cfg["dashboard.message_backlog"],
                                       namespace=namespace, serve_time=True,
                                       parameters=self._params, publish=self._gate)
        self.create_timer(cfg["dashboard.time_period"], self._send_time,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._loss = LossTracker()
        for topic in TOPICS:
            name = absolute(topic.name, namespace)
            self._loss.add_topic(name)
            qos = sensor_qos() if topic.sensor_data else reliable_qos(
                cfg["dashboard.queue_depth"])
            self.create_subscription(_msg_class(topic.typename), topic.name,
                                     self._forwarder(name), qos, raw=True)
        self._diag = Diagnostics(self, self._diagnose)
        publish = f"clients may publish on {self._gate.topic}" if self._gate else \
            "client publishing off"
        self.get_logger().info(f"Foxglove WebSocket server on {self._server.url} "
                               f"({len(TOPICS)} channels; {publish}){_layout_hint()}")

    def _send_time(self) -> None:
        self._server.broadcast_time(self.get_clock().now().nanoseconds)

    def _on_parameter_change(self, values) -> None:
        self._server.publish_parameters(values)

    def _publish_request(self, stamp_ns, frame_id: str, torque: float) -> None:
        """Publish a client's TorqueRequest (SDK thread), stamped now when unstamped."""
        msg = TorqueRequest(torque=torque)
        msg.header.frame_id = frame_id
        if stamp_ns is None:
            msg.header.stamp = self.get_clock().now().to_msg()
        else:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self._requests.publish(msg)

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
        if self._gate is not None:
            values.update(self._gate.status())
        values["parameter_nodes"] = " ".join(self._params.nodes()) or "none"
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
