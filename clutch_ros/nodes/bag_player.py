"""The ``bag_player`` node: publish a recorded bag live, with its stamps and ``/clock``.

Messages are published exactly as recorded (raw CDR bytes, header stamps untouched) at the
recorded timing divided by ``player.rate``, on the recorded topic names made relative (so
``-r __ns:=/rig1`` plays into a namespace). ``/clock`` carries the bag time, so nodes started
with ``use_sim_time:=true`` run on the recording's clock exactly as on the rig. ``rig_state``
is offered with sensor-data QoS, every other topic reliable. With ``player.loop`` the bag
repeats (the clock restarts, so sim-time nodes see time jump back; the estimator re-initialises
on the out-of-order stamp). Without it the node exits when the bag is done
(``player.exit_when_done``).
"""

from __future__ import annotations

import importlib
import threading
import time

from rclpy.node import Node

from clutch_ros.nodes.common import (
    ParamSpec,
    declare_params,
    reliable_qos,
    run_node,
    sec_to_stamp,
    sensor_qos,
)

NAME = "bag_player"
PARAMS = [
    ParamSpec("player.bag", "", "bag directory (or storage file) to play; required"),
    ParamSpec("player.rate", 1.0, "playback speed factor (2 = twice real time)", "1",
              0.01, 1000.0),
    ParamSpec("player.loop", False, "repeat the bag forever"),
    ParamSpec("player.topics", [""], "topics to play (recorded names); empty: all"),
    ParamSpec("player.publish_clock", True, "publish /clock with the bag time"),
    ParamSpec("player.clock_period", 0.01, "/clock publishing period while waiting", "s",
              0.001, 1.0),
    ParamSpec("player.start_delay", 0.5, "wait before the first message so subscribers can "
              "connect", "s", 0.0, 60.0),
    ParamSpec("player.exit_when_done", True, "shut the node down at the end of the bag"),
]


def _msg_class(typename: str):
    pkg, _, name = typename.partition("/msg/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class BagPlayerNode(Node):
    """Live bag playback with /clock (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        from rosgraph_msgs.msg import Clock

        from clutch_ros.bag.reader import BagReader

        cfg = self._cfg = declare_params(self, PARAMS)
        if not cfg["player.bag"]:
            raise ValueError("player.bag is required: the bag to play")
        self._reader = BagReader(cfg["player.bag"]).open()
        wanted = [t for t in cfg["player.topics"] if t]
        self._topics = [t for t in self._reader.topics
                        if not wanted or t in wanted or t.lstrip("/") in wanted]
        if not self._topics:
            raise ValueError(f"none of the topics {wanted} is in {cfg['player.bag']} "
                             f"(it has {list(self._reader.topics)})")
        self._pubs = {}
        for topic in self._topics:
            info = self._reader.topics[topic]
            qos = sensor_qos() if topic.endswith("rig_state") else reliable_qos()
            self._pubs[topic] = self.create_publisher(_msg_class(info.typename),
                                                      topic.lstrip("/"), qos)
        self._clock_pub = (self.create_publisher(Clock, "/clock", 10)
                           if cfg["player.publish_clock"] else None)
        self.played = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name="bag_player", daemon=True)
        self._thread.start()
        self.get_logger().info(f"playing {', '.join(self._topics)} from {cfg['player.bag']} "
                               f"at {cfg['player.rate']}x")

    def _publish_clock(self, bag_ns: int) -> None:
        if self._clock_pub is not None:
            from rosgraph_msgs.msg import Clock

            msg = Clock()
            sec_to_stamp(bag_ns * 1e-9, msg.clock)
            self._clock_pub.publish(msg)

    def _play(self) -> None:
        cfg = self._cfg
        try:
            self._stop.wait(cfg["player.start_delay"])
            while not self._stop.is_set():
                self._play_once(cfg["player.rate"], cfg["player.clock_period"])
                if not cfg["player.loop"]:
                    break
            self.get_logger().info(f"bag done: {self.played} messages published")
        except Exception as err:  # noqa: BLE001 - a corrupt bag is reported, not a crash
            self.get_logger().error(f"playback stopped: {err}")
        if cfg["player.exit_when_done"] and not self._stop.is_set():
            import rclpy

            rclpy.try_shutdown()

    def _play_once(self, rate: float, clock_period: float) -> None:
        start_wall = time.monotonic()
        start_bag = None
        for topic, bag_ns, data in self._reader.messages(self._topics, raw=True):
            if self._stop.is_set():
                return
            start_bag = bag_ns if start_bag is None else start_bag
            due = start_wall + (bag_ns - start_bag) * 1e-9 / rate
            while (wait := due - time.monotonic()) > 0.0:
                self._publish_clock(start_bag + int((time.monotonic() - start_wall)
                                                    * rate * 1e9))
                if self._stop.wait(min(wait, clock_period)):
                    return
            self._publish_clock(bag_ns)
            self._pubs[topic].publish(bytes(data))
            self.played += 1

    def close(self) -> None:
        """Stop playback and close the bag."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._reader.close()


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros bag_player``."""
    return run_node(NAME, __doc__, PARAMS, BagPlayerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
