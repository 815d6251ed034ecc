"""The ``recorder`` node: every clutch topic into a rosbag2 bag (MCAP default) via rosbags.

Subscriptions are *raw* (the CDR bytes as they arrived over DDS are written unchanged, so the
recording is lossless and costs no deserialization). Reliable topics are subscribed with
KEEP_ALL history so a burst is queued rather than overwritten; ``rig_state`` (sensor-data QoS,
best effort) is subscribed best-effort with a deep queue. The bag's timestamps are the receive
times on the node clock (``use_sim_time`` gives sim time), as ``ros2 bag record`` stores them.
Counts per topic are logged on shutdown and published on ``/diagnostics``; the writer verifies
on close that the bag declares and stores exactly the counts received.
"""

from __future__ import annotations

import time
from pathlib import Path

from rclpy.node import Node

from clutch_ros.nodes.common import Diagnostics, ParamSpec, declare_params, run_node

NAME = "recorder"
#: topic (relative) -> (rclpy message type path, reliable?)
DEFAULT_TOPICS = {
    "rig_state": ("clutch_msgs.msg.RigState", False),
    "clutch_estimate": ("clutch_msgs.msg.ClutchEstimate", True),
    "torque_request": ("clutch_msgs.msg.TorqueRequest", True),
    "pressure_command": ("clutch_msgs.msg.PressureCommand", True),
    "can_frames": ("clutch_msgs.msg.CanFrame", True),
}
PARAMS = [
    ParamSpec("recorder.output", "", "bag directory to create (must not exist); empty: "
              "runs/rec-YYYYmmdd-HHMMSS in the working directory"),
    ParamSpec("recorder.storage", "mcap", "storage format", choices=("mcap", "sqlite3")),
    ParamSpec("recorder.topics", list(DEFAULT_TOPICS), "topics to record (relative names of "
              "the clutch topics)"),
]


def _import(path: str):
    module, _, name = path.rpartition(".")
    return getattr(__import__(module, fromlist=[name]), name)


class RecorderNode(Node):
    """Raw, lossless recorder of the clutch topics (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from clutch_ros.bag.writer import BagWriter

        cfg = declare_params(self, PARAMS)
        if cfg["recorder.storage"] not in ("mcap", "sqlite3"):
            raise ValueError(f"recorder.storage must be mcap or sqlite3, got "
                             f"{cfg['recorder.storage']!r}")
        output = cfg["recorder.output"] or f"runs/rec-{time.strftime('%Y%m%d-%H%M%S')}"
        self.output = Path(output)
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self._writer = BagWriter(self.output, storage=cfg["recorder.storage"],
                                 namespace=self.get_namespace()).open()
        self.received: dict[str, int] = {}
        for topic in cfg["recorder.topics"]:
            if topic not in DEFAULT_TOPICS:
                raise ValueError(f"recorder.topics: unknown topic {topic!r} "
                                 f"(known: {', '.join(DEFAULT_TOPICS)})")
            type_path, reliable = DEFAULT_TOPICS[topic]
            msg_type = _import(type_path)
            name = self._writer.add_topic(topic, type_path.replace(".msg.", "/msg/"))
            if reliable:
                qos = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                                 reliability=ReliabilityPolicy.RELIABLE)
            else:
                qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.received[name] = 0
            self.create_subscription(msg_type, topic, self._writer_for(name), qos, raw=True)
        self._diag = Diagnostics(self, self._diagnose)
        self.get_logger().info(f"recording {', '.join(self.received)} to {self.output}")

    def _writer_for(self, name: str):
        def write(data: bytes) -> None:
            self.received[name] += 1
            self._writer.write_raw(name, self.get_clock().now().nanoseconds, data)
        return write

    def _diagnose(self):
        values = {f"received{k}": v for k, v in self.received.items()}
        values.update({f"written{k}": v for k, v in self._writer.written.items()})
        values["output"] = str(self.output)
        return "OK", f"recording to {self.output}", values

    def close(self) -> dict[str, int]:
        """Finish the bag (verifying counts) and return messages written per topic."""
        written = self._writer.close()
        lost = {k: self.received[k] - written.get(k, 0) for k in self.received
                if self.received[k] != written.get(k, 0)}
        if lost:
            self.get_logger().error(f"messages received but not written: {lost}")
        self.get_logger().info(f"bag {self.output}: {written}")
        return written


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros recorder``."""
    return run_node(NAME, __doc__, PARAMS, RecorderNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
