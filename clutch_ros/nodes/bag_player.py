"""The ``bag_player`` node: publish a recorded bag live, with its stamps and ``/clock``.

Messages are published exactly as recorded (raw CDR bytes, header stamps untouched) at the
recorded timing divided by ``player.rate``, on the recorded topic names made relative (so
``-r __ns:=/rig1`` plays into a namespace). ``/clock`` carries the bag time, so nodes started
with ``use_sim_time:=true`` run on the recording's clock exactly as on the rig. Every topic is
offered reliable (REP 2003; depth 200), so reliable and sensor-data subscribers both receive
it. ``player.start_offset`` skips the bag's first seconds (each pass). ``player.topics``
selects topics
(recorded names, with or without the leading slash; a name the bag lacks is an error).
``player.wait_for_subscribers`` holds playback until every played topic (and ``/clock``)
has that many subscribers, so no early message is published into the void. With
``player.loop`` the bag repeats (the clock restarts, so sim-time nodes see time jump back;
the estimator re-initialises on the out-of-order stamp). Without it the node exits when the
bag is done (``player.exit_when_done``).

Live control: ``player.rate``, ``player.loop``, ``player.start_offset`` (from the next pass),
``player.clock_period`` and ``player.exit_when_done`` apply at once when set; a new rate
continues from the current bag time. The service ``~/set_paused``
(``clutch_msgs/srv/SetPaused``) pauses and resumes: while paused only ``/clock`` is published,
holding the bag time of the pause. The other parameters are read-only (their descriptions say
why).

The bag is checked on open (metadata.yaml against the storage) and every message is decoded
before it is published, so a corrupt bag is never played as garbage: playback stops with one
``playback stopped: FILE: cause`` error and the node exits with code 1 (2 when the bag cannot
be opened at all). At the end one line ``player summary: {json}`` gives the messages
published, the bag time span and the wall time it took.
"""

from __future__ import annotations

import importlib
import json
import math
import threading
import time

import rclpy
from clutch_msgs.srv import SetPaused
from rcl_interfaces.msg import SetParametersResult
from rclpy.duration import Duration
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from clutch_ros import interfaces
from clutch_ros.bag.diagnose import blame_file
from clutch_ros.bag.errors import BagCorruptError
from clutch_ros.bag.reader import BagReader
from clutch_ros.nodes.parameters import HARDWARE_ID_PARAM, ParamSpec, declare_params
from clutch_ros.nodes.qos import publisher_qos, reliable_qos
from clutch_ros.nodes.runner import run_node
from clutch_ros.nodes.stamps import sec_to_stamp

NAME = "bag_player"
#: [s] at most this long, before exiting when done, for reliable readers to acknowledge
ACK_WAIT = 5.0
PARAMS = [
    ParamSpec("player.bag", "", "bag directory (or storage file) to play; required; read-only: "
              "the bag is opened and checked at start", read_only=True),
    ParamSpec("player.rate", 1.0, "playback speed factor (2 = twice real time); live",
              "1", 0.01, 1000.0),
    ParamSpec("player.start_offset", 0.0, "skip this much of the bag's beginning (each pass); "
              "live from the next pass", "s", 0.0, 1e9),
    ParamSpec("player.loop", False, "repeat the bag forever; live"),
    ParamSpec("player.topics", [""], "topics to play (recorded names); empty: all; read-only: "
              "the publishers are created at start", read_only=True),
    ParamSpec("player.publish_clock", True, "publish /clock with the bag time; read-only: "
              "the /clock publisher is created at start", read_only=True),
    ParamSpec("player.clock_period", 0.01, "/clock publishing period while waiting or "
              "paused; live", "s", 0.001, 1.0),
    ParamSpec("player.start_delay", 0.5, "wait before the first message so subscribers can "
              "connect; read-only: used once at start", "s", 0.0, 60.0, read_only=True),
    ParamSpec("player.wait_for_subscribers", 0, "before playing, wait until every played "
              "topic and /clock has this many subscribers (0: do not wait); read-only: used "
              "once at start", "", 0, 1000, read_only=True),
    ParamSpec("player.wait_timeout", 30.0, "give up waiting for subscribers after this "
              "(playback then starts anyway, with a warning); read-only: used once at start",
              "s", 0.0, 3600.0, read_only=True),
    ParamSpec("player.exit_when_done", True, "shut the node down at the end of the bag; live"),
    HARDWARE_ID_PARAM,
]
#: parameters applied live (the rest are declared read-only)
LIVE = ("player.rate", "player.start_offset", "player.loop", "player.clock_period",
        "player.exit_when_done")
_OWN = frozenset(spec.name for spec in PARAMS)


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
            # a clutch topic as its own publisher offers it (interfaces.TOPICS), any other
            # reliable: a default and a sensor-data subscriber both receive the replay
            qos = publisher_qos(topic) if interfaces.topic(topic) else reliable_qos()
            self._pubs[topic] = self.create_publisher(_msg_class(info.typename),
                                                      topic.lstrip("/"), qos)
        self._clock_pub = (self.create_publisher(Clock, "/clock", 10)
                           if cfg["player.publish_clock"] else None)
        self.played = 0
        self._lock = threading.Lock()
        self._paused = False
        self._bag_ns = None  # bag time of the last published message [ns]
        # (wall [s], bag [ns]) the timing counts from; None: re-anchor
        self._anchor: tuple[float, int] | None = None
        self._resume = threading.Event()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_service(SetPaused, "~/set_paused", self._on_set_paused)
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
                before = self.played
                self._play_once()
                if not cfg["player.loop"]:
                    break
                if self.played == before:  # e.g. start_offset past the end: do not spin
                    self.get_logger().warning("a pass published nothing; loop stopped")
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
            # a reliable reader may not have acknowledged the last messages yet (a busy
            # machine): exiting now would lose them, so wait (bounded) for the acks first
            for pub in self._pubs.values():
                pub.wait_for_all_acked(Duration(seconds=ACK_WAIT))
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

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Apply the live parameters (ranges checked by ROS); a new rate re-anchors timing."""
        for p in params:  # its own fixed ones (ROS refuses other read-only ones, rt.*, itself)
            if p.name in _OWN and p.name not in LIVE:
                return SetParametersResult(successful=False, reason=f"{p.name} is read-only")
        with self._lock:
            for p in params:
                if p.name in LIVE:
                    self._cfg[p.name] = p.value
                if p.name == "player.rate":
                    self._anchor = None  # continue from the current bag time at the new rate
        self._resume.set()  # wake a waiting playback thread so the change applies now
        return SetParametersResult(successful=True)

    def _on_set_paused(self, request, response):
        """Service ``~/set_paused``: pause (True) or resume (False) playback."""
        with self._lock:
            if self._paused != request.paused:
                self._paused = request.paused
                self._anchor = None
                self.get_logger().info("paused" if request.paused else "resumed")
            response.paused = self._paused
            response.bag_time = (self._bag_ns or 0) * 1e-9
        self._resume.set()
        return response

    def _due(self, bag_ns: int) -> float:
        """Return the wall time [s] (monotonic) at which ``bag_ns`` is due; under the lock."""
        if self._anchor is None:
            start = self._bag_ns if self._bag_ns is not None and self._bag_ns <= bag_ns \
                else bag_ns
            self._anchor = (time.monotonic(), start)
        wall, bag = self._anchor
        return wall + (bag_ns - bag) * 1e-9 / self._cfg["player.rate"]

    def _wait_until_due(self, bag_ns: int) -> bool:
        """Wait (publishing /clock) until ``bag_ns`` is due and not paused; False: stopped."""
        while not self._stop.is_set():
            with self._lock:
                paused = self._paused
                wait = math.inf if paused else self._due(bag_ns) - time.monotonic()
                held = self._bag_ns if self._bag_ns is not None else bag_ns
                anchor = self._anchor  # set by _due() above unless paused
                now_bag = held if paused or anchor is None else anchor[1] + int(
                    (time.monotonic() - anchor[0]) * self._cfg["player.rate"] * 1e9)
                period = self._cfg["player.clock_period"]
            if wait <= 0.0:
                return True
            self._publish_clock(max(min(now_bag, bag_ns), held))
            self._resume.clear()
            self._resume.wait(min(wait, period))
        return False

    def _play_once(self) -> None:
        with self._lock:
            offset = int(self._cfg["player.start_offset"] * 1e9)
            self._anchor, self._bag_ns = None, None
        start = self._reader.start_ns + offset if offset else None
        for topic, bag_ns, data in self._reader.messages(self._topics, raw=True,
                                                         start_ns=start):
            if self._stop.is_set():
                return
            self._check(topic, bag_ns, data)  # then published as the recorded bytes
            if not self._wait_until_due(bag_ns):
                return
            self._publish_clock(bag_ns)
            self._pubs[topic].publish(bytes(data))
            with self._lock:
                self._bag_ns = bag_ns
            self.played += 1

    def close(self) -> None:
        """Stop playback and close the bag."""
        self._stop.set()
        self._resume.set()
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
