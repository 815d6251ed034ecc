"""The ``recorder`` node: every clutch topic into a rosbag2 bag (MCAP default) via rosbags.

Subscriptions are *raw* (the CDR bytes as they arrived over DDS are written unchanged, so the
recording is lossless and costs no deserialization). Reliable topics are subscribed with
KEEP_ALL history so a burst is queued rather than overwritten; ``rig_state`` (sensor-data QoS,
best effort) is subscribed best-effort with a deep queue (``recorder.queue_depth``). The bag's
timestamps are the receive times on the node clock (``use_sim_time`` gives sim time), as
``ros2 bag record`` stores them.

Loss accounting (:class:`clutch_ros.nodes.loss_tracker.LossTracker`): every sample carries its
publisher's DDS sequence number, so a gap is counted exactly, per topic, as ``dropped`` and
stored in the bag (``custom_data`` ``clutch_ros.dropped``, via ``BagWriter.mark_dropped``);
samples a publisher sent before the first one seen here are ``missed_at_start``. Counts
(received, written, dropped) are on ``/diagnostics`` (WARN once anything was dropped) and,
on shutdown, in one log line ``recorder summary: {json}`` and in the bag's ``custom_data``.
The writer verifies on close that the bag declares and stores exactly the counts received.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from clutch_ros.bag.writer import BagWriter
from clutch_ros.nodes.common import Diagnostics, ParamSpec, declare_params, run_node
from clutch_ros.nodes.loss_tracker import LossTracker, format_counts

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
    ParamSpec("recorder.queue_depth", 10000, "subscription queue of best-effort topics "
              "(rig_state): samples a burst may run ahead of the recorder", "messages",
              10, 1000000),
]


def _import(path: str):
    module, _, name = path.rpartition(".")
    return getattr(__import__(module, fromlist=[name]), name)


class RecorderNode(Node):
    """Raw, lossless recorder of the clutch topics (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)


        cfg = declare_params(self, PARAMS)
        if cfg["recorder.storage"] not in ("mcap", "sqlite3"):
            raise ValueError(f"recorder.storage must be mcap or sqlite3, got "
                             f"{cfg['recorder.storage']!r}")
        for topic in cfg["recorder.topics"]:
            if topic not in DEFAULT_TOPICS:
                raise ValueError(f"recorder.topics: unknown topic {topic!r} "
                                 f"(known: {', '.join(DEFAULT_TOPICS)})")
        output = cfg["recorder.output"] or f"runs/rec-{time.strftime('%Y%m%d-%H%M%S')}"
        self.output = Path(output)
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self._writer = BagWriter(self.output, storage=cfg["recorder.storage"],
                                 namespace=self.get_namespace()).open()
        self.loss = LossTracker()
        for topic in cfg["recorder.topics"]:
            type_path, reliable = DEFAULT_TOPICS[topic]
            name = self._writer.add_topic(topic, type_path.replace(".msg.", "/msg/"))
            if reliable:
                qos = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                                 reliability=ReliabilityPolicy.RELIABLE)
            else:
                qos = QoSProfile(depth=cfg["recorder.queue_depth"],
                                 reliability=ReliabilityPolicy.BEST_EFFORT)
            self.loss.add_topic(name)
            self.create_subscription(_import(type_path), topic, self._writer_for(name), qos,
                                     raw=True)
        self._diag = Diagnostics(self, self._diagnose)
        self.get_logger().info(f"recording {', '.join(self.loss.topics)} to {self.output}")

    @property
    def received(self) -> dict[str, int]:
        """Messages received per topic (absolute name) [messages]."""
        return self.loss.counts("received")

    def _writer_for(self, name: str):
        loss, writer, clock = self.loss, self._writer, self.get_clock()

        def write(data: bytes, info) -> None:
            gap = loss.received(name, info)
            if gap:
                writer.mark_dropped(name, gap)
            writer.write_raw(name, clock.now().nanoseconds, data)
        return write

    def _diagnose(self):
        values = {}
        for topic, stats in self.loss.topics.items():
            values[f"received{topic}"] = stats.received
            values[f"written{topic}"] = self._writer.written.get(topic, 0)
            values[f"dropped{topic}"] = stats.dropped
            values[f"missed_at_start{topic}"] = stats.missed_at_start
        values["output"] = str(self.output)
        values["loss_tracked"] = self.loss.tracked
        dropped = sum(s.dropped for s in self.loss.topics.values())
        if dropped:
            return "WARN", f"recording to {self.output}; {dropped} messages lost", values
        return "OK", f"recording to {self.output}", values

    def summary(self) -> dict:
        """Return per topic: received, written, dropped, missed_at_start [messages]."""
        return {topic: {"received": s.received, "written": self._writer.written.get(topic, 0),
                        "dropped": s.dropped, "missed_at_start": s.missed_at_start}
                for topic, s in self.loss.topics.items()}

    def close(self) -> dict[str, int]:
        """Finish the bag (verifying counts) and return messages written per topic."""
        if self._writer.closed:
            return dict(self._writer.written)
        self._writer.set_custom_data("clutch_ros.received", format_counts(self.received))
        self._writer.set_custom_data("clutch_ros.missed_at_start",
                                     format_counts(self.loss.counts("missed_at_start")))
        self._writer.set_custom_data("clutch_ros.loss_tracked", str(self.loss.tracked).lower())
        written = self._writer.close()
        lost = {k: n - written.get(k, 0) for k, n in self.received.items()
                if n != written.get(k, 0)}
        if lost:
            self.get_logger().error(f"messages received but not written: {lost}")
        self.get_logger().info(f"recorder summary: {json.dumps(self.summary(), sort_keys=True)}")
        return written


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros recorder``."""
    return run_node(NAME, __doc__, PARAMS, RecorderNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
