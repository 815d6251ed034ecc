"""The ``bag_player`` node: publish a recorded bag live, with its stamps and ``/clock``.

Messages are published exactly as recorded (raw CDR bytes, header stamps untouched) at the
recorded timing divided by ``player.rate``, on the recorded topic names made relative (so
``-r __ns:=/rig1`` plays into a namespace). ``/clock`` carries the bag time, so nodes started
with ``use_sim_time:=true`` run on the recording's clock exactly as on the rig. ``rig_state``
is offered with sensor-data QoS, every other topic reliable. ``player.topics`` selects topics
(recorded names, with or without the leading slash; a name the bag lacks is an error).
``player.wait_for_subscribers`` holds playback until every played topic (and ``/clock``)
has that many subscribers, so no early message is published into the void. With
``player.loop`` the bag repeats (the clock restarts, so sim-time nodes see time jump back;
the estimator re-initialises on the out-of-order stamp). Without it the node exits when the
bag is done (``player.exit_when_done``).

The bag is checked on open (metadata.yaml against the storage) and every message is decoded
before it is published, so a corrupt bag is never played as garbage: playback stops with one
``playback stopped: FILE: cause`` error and the node exits with code 1 (2 when the bag cannot
be opened at all). At the end one line ``player summary: {json}`` gives the messages
published, the bag time span and the wall time it took.
"""

from __future__ import annotations

import importlib
import json
import threading
import time

from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from clutch_ros.bag.diagnose import blame_file
from clutch_ros.bag.errors import BagCorruptError
from clutch_ros.bag.reader import BagReader
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
    ParamSpec("player.wait_for_subscribers", 0, "before playing, wait until every played "
              "topic and /clock has this many subscribers (0: do not wait)", "", 0, 1000),
    ParamSpec("player.wait_timeout", 30.0, "give up waiting for subscribers after this "
              "(playback then starts anyway, with a warning)", "s", 0.0, 3600.0),
    ParamSpec("player.exit_when_done", True, "shut the node down at the end of the bag"),
]


def _msg_class(typename: str):
    pkg, _, name = typename.partition("/msg/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class BagPlayerNode(Node):
    """Live bag playback with /clock (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)


        cfg = self._cfg = declare_params(self, PARAMS)
        if not cfg["player.bag"]:
            raise ValueError("player.bag is required: the bag to play")
        #: the error that stopped playback (None while fine)
        self.error: str | None = None
        self._reader = BagReader(cfg["player.bag"], verify=True).open()
        try:
            self._topics = self._select(cfg["player.topics"])
            self._reader.check_types(self._topics)
        except Exception:
            self._reader.close()
            raise
        self._pubs = {}
        self._types = {t: self._reader.topics[t].typename for t in self._topics}
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

    def _select(self, topics: list[str]) -> list[str]:
        have = list(self._reader.topics)
        wanted = [t for t in topics if t]
        if not wanted:
            return have
        missing = [t for t in wanted if t not in have and "/" + t.lstrip("/") not in have]
        if missing:
            raise ValueError(f"player.topics: {', '.join(missing)} not in {self._reader.path} "
                             f"(it has {', '.join(have) or 'no topics'})")
        return [t for t in have if t in wanted or t.lstrip("/") in wanted]

    def _publish_clock(self, bag_ns: int) -> None:
        if self._clock_pub is not None:
            from rosgraph_msgs.msg import Clock

            msg = Clock()
            sec_to_stamp(bag_ns * 1e-9, msg.clock)
            self._clock_pub.publish(msg)

    def _wait_for_subscribers(self) -> None:
        need = self._cfg["player.wait_for_subscribers"]
        if need <= 0:
            return
        pubs = list(self._pubs.values()) + ([self._clock_pub] if self._clock_pub else [])
        end = time.monotonic() + self._cfg["player.wait_timeout"]
        while not self._stop.is_set():
            if all(p.get_subscription_count() >= need for p in pubs):
                return
            if time.monotonic() > end:
                self.get_logger().warning(f"playing although not every topic has {need} "
                                          "subscriber(s) yet")
                return
            self._stop.wait(0.05)

    def _play(self) -> None:
        cfg = self._cfg
        wall = 0.0
        try:
            self._wait_for_subscribers()
            self._stop.wait(cfg["player.start_delay"])
            start = time.monotonic()
            while not self._stop.is_set():
                self._play_once(cfg["player.rate"], cfg["player.clock_period"])
                if not cfg["player.loop"]:
                    break
            wall = time.monotonic() - start
        except Exception as err:  # noqa: BLE001 - a corrupt bag is reported, not a crash
            if self._stop.is_set() or not self.context.ok():
                return  # shut down (Ctrl-C) while publishing: not a playback error
            self.error = str(err)
            self.get_logger().error(f"playback stopped: {err}")
        reader = self._reader
        span = (reader.end_ns - reader.start_ns) / 1e9 if reader.message_count else 0.0
        summary = {"published": self.played, "bag_span_s": span, "wall_s": wall,
                   "rate": cfg["player.rate"], "topics": self._topics, "error": self.error}
        self.get_logger().info(f"player summary: {json.dumps(summary)}")
        if cfg["player.exit_when_done"] and not self._stop.is_set():
            import rclpy

            rclpy.try_shutdown()

    def _check(self, topic: str, bag_ns: int, data) -> None:
        """Decode one message so a corrupt one stops playback instead of being published."""
        typename = self._types[topic]
        try:
            self._reader.store.deserialize_cdr(data, typename)
        except Exception as err:  # noqa: BLE001 - SerdeError, struct.error, ...
            raise BagCorruptError(blame_file(self._reader.path),
                                  f"message {self.played + 1} on {topic} at {bag_ns} ns cannot "
                                  f"be decoded as {typename}: {err}") from err

    def _play_once(self, rate: float, clock_period: float) -> None:
        start_wall = time.monotonic()
        start_bag = None
        for topic, bag_ns, data in self._reader.messages(self._topics, raw=True):
            if self._stop.is_set():
                return
            self._check(topic, bag_ns, data)  # then published as the recorded bytes
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
    """Console entry point: ``ros2 run clutch_ros bag_player``.

    Returns 0 after a complete playback, 1 when playback stopped on an error, 2 when the bag
    cannot be opened or the parameters are invalid (one error line, no traceback).
    """
    nodes: list[BagPlayerNode] = []

    def factory() -> BagPlayerNode:
        nodes.append(BagPlayerNode())
        return nodes[-1]

    code = run_node(NAME, __doc__, PARAMS, factory, args)  # bad bag/params: one line, 2
    return 1 if nodes and nodes[0].error else code


if __name__ == "__main__":
    raise SystemExit(main())
