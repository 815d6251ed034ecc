"""The ``recorder`` node: clutch topics (or any topics) into rosbag2 bags via rosbags.

Topics: ``recorder.topics`` (default: every clutch topic of
:data:`clutch_ros.interfaces.TOPICS`, ``pump_request``, ``can_frames`` and ``/diagnostics``
included). Each topic is subscribed once the ROS graph shows a publisher of it
(looked up at start and every 0.25 s after), as ``ros2 bag record`` does; a name outside
that table is recorded with the type the graph advertises for it (its type must be in the
bag typestore: the clutch messages and the ROS 2 base distribution).

Subscriptions are *raw* (the CDR bytes as they arrived over DDS are written unchanged, so the
recording is lossless and costs no deserialization). The bag's timestamps are the receive
times on the node clock (``use_sim_time`` gives sim time), as ``ros2 bag record`` stores them.

Splitting (``recorder.split_size`` [bytes] and/or ``recorder.split_duration`` [s], live):
``recorder.output`` becomes a directory of complete bags ``part_0000``, ``part_0001`` ...,
each a rosbag2 folder with its own metadata.yaml and counts; a part is closed and the next
opened when its message bytes or its time span reach a limit (a bag folder per split, not
rosbag2's files inside one bag, so every part replays and imports on its own). Without limits
``recorder.output`` is the bag itself.

QoS: a topic whose publishers (when the recorder subscribes, as ``ros2 bag record`` decides)
all offer reliable is subscribed reliable with KEEP_ALL history, so a burst is queued rather
than overwritten; otherwise best effort with a ``recorder.queue_depth`` queue, which matches
every publisher. The bag records, per topic, the QoS each publisher offers (one profile per
publisher, as ``ros2 bag record`` stores them), read from the ROS graph when the topic is added
to the bag; DDS discovery does not carry the history and depth, so those (and everything when
no publisher is known yet) come from the topic's publisher profile in
:data:`clutch_ros.interfaces.TOPICS`. ``ros2 bag play`` offers them again.

Crash safety (MCAP): the open chunk is closed before its first message is
``recorder.chunk_interval`` old (1 s; checked on every message and every tenth of it), written
with its CRC and message index, flushed and (``recorder.fsync``) fsync'd
(:mod:`clutch_ros.bag.chunked`). A recorder killed (SIGKILL, power cut) leaves a file without
summary whose messages older than that are all on disk; ``clutch replay --recover`` reads it.

Shutdown: on SIGINT or SIGTERM the node stops its timers (its own ``/diagnostics`` too) and
drains what DDS still queues for it, taking from its subscriptions directly (no executor),
until none had anything for ``recorder.drain_quiet`` (0.2 s) or ``recorder.drain_timeout``
(1 s) passed, however much the other nodes still publish; a second signal ends the drain at
once. Whatever is still queued then is taken and counted, not written
(``unwritten_at_shutdown``, and in the bag's ``clutch_ros.dropped``), and the bag is closed:
complete (summary, metadata.yaml) well within 3 s of the signal, before ``ros2 launch``
escalates to SIGTERM (5 s). The exit code is 0 for either signal.

Loss accounting (:class:`clutch_ros.nodes.loss_tracker.LossTracker`): every sample carries its
publisher's DDS sequence number, so a gap is counted exactly, per topic, as ``dropped`` and
stored in the bag (``custom_data`` ``clutch_ros.dropped``); samples a publisher sent before the
first one seen here are ``missed_at_start``. (Tail losses once seen here, 90-220 of a
20,000-message burst neither written nor counted, came from a reliable topic subscribed best
effort because its publisher was discovered late; topics are therefore subscribed only once a
publisher is known.) Counts (received, written, dropped) are on ``/diagnostics`` (WARN once
anything was dropped) and, on shutdown, in one log line ``recorder summary: {json}`` and in
the bags' ``custom_data``. Exact means: with reliable publishers every sample taken is either
written or counted (a KEEP_LAST publisher's overwritten samples show as gaps). Samples lost
in transport *after* the last one received (a best-effort publisher's, or a reliable tail
whose repair, on the writer's next heartbeat up to 3 s later with Fast DDS, comes after the
drain) are invisible to the recorder; a drain as long as ``drain_quiet`` 3.5 s waits for that
repair. Best-effort topics are marked ``best_effort`` in the summary.
"""

from __future__ import annotations

import importlib
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from clutch_ros import interfaces
from clutch_ros.bag.writer import BagWriter, qos_of
from clutch_ros.errors import ClutchError
from clutch_ros.nodes.diagnostics import Diagnostics
from clutch_ros.nodes.drain import drain, take
from clutch_ros.nodes.loss_tracker import LossTracker, format_counts
from clutch_ros.nodes.parameters import (
    HARDWARE_ID_PARAM,
    ParamSpec,
    declare_params,
    format_help,
    help_requested,
)
from clutch_ros.nodes.qos import spec_of
from clutch_ros.nodes.realtime import REALTIME_PARAMS
from clutch_ros.nodes.runner import make_executor, start_realtime

NAME = "recorder"
RESOLVE_PERIOD = 0.25  # [s] how often topics without a publisher yet are looked up
CHUNK_CHECKS = 10  # chunk-interval checks per recorder.chunk_interval, besides every message
DISCARD_LIMIT = 0.2  # [s] at most this long spent counting what is queued after the drain
#: clutch topic -> its ROS type "pkg/msg/Name" (:data:`clutch_ros.interfaces.TOPICS`)
DEFAULT_TOPICS = {t.name: t.typename for t in interfaces.TOPICS}
PARAMS = [
    ParamSpec("recorder.output", "", "bag directory to create (must not exist); empty: "
              "runs/rec-YYYYmmdd-HHMMSS in the working directory; with splitting, the "
              "directory of the parts; read-only: opened at start", read_only=True),
    ParamSpec("recorder.storage", "mcap", "storage format; read-only: the bag is opened at "
              "start", choices=("mcap", "sqlite3"), read_only=True),
    ParamSpec("recorder.topics", list(DEFAULT_TOPICS), "topics to record (clutch topics by "
              "relative name, any other topic with the type the graph advertises); "
              "read-only: subscriptions are made at start", read_only=True),
    ParamSpec("recorder.discovery_wait", 1.0, "at start, wait up to this long for the "
              "publishers of the recorded topics to be discovered before subscribing (a topic "
              "whose publisher appears later is subscribed then); read-only: used once",
              "s", 0.0, 10.0, read_only=True),
    ParamSpec("recorder.queue_depth", 10000, "subscription queue of best-effort topics "
              "(rig_state): samples a burst may run ahead of the recorder; read-only: a DDS "
              "reader's history depth is fixed when it is created", "messages",
              10, 1000000, read_only=True),
    ParamSpec("recorder.split_size", 0, "start a new part when the current one holds this "
              "many message bytes; 0: no size split; live", "B", 0, 2**62),
    ParamSpec("recorder.split_duration", 0.0, "start a new part when the current one spans "
              "this long (receive time); 0: no time split; live", "s", 0.0, 1e7),
    ParamSpec("recorder.chunk_interval", 1.0, "close, write and flush the open MCAP chunk "
              "before its first message is this old: a crash loses at most this much; "
              "read-only: the bag is opened at start", "s", 0.05, 60.0, read_only=True),
    ParamSpec("recorder.fsync", True, "fsync each chunk as it is written (a power cut, not "
              "only a crash of the recorder, loses at most recorder.chunk_interval); "
              "read-only: the bag is opened at start", read_only=True),
    ParamSpec("recorder.drain_quiet", 0.2, "at shutdown, keep taking queued messages until "
              "none arrived for this long (3.5 s waits for a Fast DDS reliable writer's "
              "heartbeat to repair a tail lost in transport); live", "s", 0.0, 60.0),
    ParamSpec("recorder.drain_timeout", 1.0, "at shutdown, stop draining after this long, "
              "however much is still published (keep the close within ros2 launch's 5 s "
              "before SIGTERM); live", "s", 0.0, 600.0),
    HARDWARE_ID_PARAM,
]
LIVE = ("recorder.split_size", "recorder.split_duration", "recorder.drain_quiet",
        "recorder.drain_timeout")


def _msg_class(typename: str):
    pkg, _, name = typename.partition("/msg/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class RecorderNode(Node):
    """Raw recorder with exact loss accounting and optional splitting (see module doc)."""

    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)
        cfg = self._cfg = declare_params(self, PARAMS)
        if cfg["recorder.storage"] not in ("mcap", "sqlite3"):
            raise ValueError(f"recorder.storage must be mcap or sqlite3, got "
                             f"{cfg['recorder.storage']!r}")
        output = cfg["recorder.output"] or f"runs/rec-{time.strftime('%Y%m%d-%H%M%S')}"
        self.output = Path(output)
        if self.output.exists():
            raise ValueError(f"recorder.output {self.output} exists already; bags are never "
                             "overwritten")
        self.output.parent.mkdir(parents=True, exist_ok=True)
        self._split = bool(cfg["recorder.split_size"] or cfg["recorder.split_duration"])
        self.parts: list[Path] = []
        self._closed_written: dict[str, int] = {}
        self._types: dict[str, str] = {}  # absolute topic -> type
        self._subs: list[tuple[Any, str, Any]] = []  # subscription, topic, its write callback
        self.unwritten: dict[str, int] = {}  # taken at shutdown but not written, per topic
        self._qos: dict[str, list] = {}  # absolute topic -> offered QoS recorded (rosbags)
        self._writer = self._new_part()
        self.loss = LossTracker()
        self._pending = []
        self._best_effort: set[str] = set()
        self._await_publishers([t for t in cfg["recorder.topics"] if t in DEFAULT_TOPICS],
                               cfg["recorder.discovery_wait"])
        self._pending = [t for t in dict.fromkeys(cfg["recorder.topics"]) if t]
        for topic in self._pending:  # in the bag and the counts from the start, 0 or not
            if topic in DEFAULT_TOPICS:
                self._register(topic, DEFAULT_TOPICS[topic])
        self._resolver = None
        self._resolve_pending()
        if self._pending:
            self._resolver = self.create_timer(RESOLVE_PERIOD, self._resolve_pending)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose)
        self._chunk_check = cfg["recorder.chunk_interval"] / CHUNK_CHECKS  # [s]
        self._chunk_timer = self.create_timer(self._chunk_check, self._close_chunk_if_due)
        waiting = f" (waiting for {', '.join(self._pending)})" if self._pending else ""
        self.get_logger().info(f"recording {', '.join(self.loss.topics) or 'nothing yet'}"
                               f"{waiting} to {self.output}")

    # -- topics ---------------------------------------------------------------------------
    def _await_publishers(self, topics: list[str], timeout: float) -> None:
        """Wait up to ``timeout`` [s] until every topic in ``topics`` has a known publisher.

        Right after the node starts, DDS discovery has not seen the publishers yet, and the
        reliability of a subscription is chosen from what the publishers offer
        (:meth:`_offered_reliable`). The graph cache is filled by the middleware's own
        discovery thread, so polling it needs no spinning.
        """
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not all(
                self.count_publishers(self.resolve_topic_name(t)) for t in topics):
            time.sleep(0.02)

    def _offered_reliable(self, topic: str) -> bool:
        """Return True when ``topic`` has publishers and every one offers reliable.

        With none (one that vanished since it was seen), best effort: it matches any publisher.
        """
        infos = self.get_publishers_info_by_topic(self.resolve_topic_name(topic))
        return bool(infos) and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                                   for i in infos)

    def _offered_qos(self, topic: str) -> list:
        """Return the offered QoS to record for ``topic`` (rosbags profiles; empty: default).

        One profile per publisher the graph shows (:func:`~clutch_ros.nodes.qos.spec_of`: what
        discovery leaves unknown, the history and depth, from the table); the table's
        publisher profile while none is known. Empty for an unknown topic without publishers
        (the writer's default).
        """
        known = interfaces.topic(topic)
        table = known.publisher if known is not None else None
        infos = self.get_publishers_info_by_topic(self.resolve_topic_name(topic))
        specs = [spec_of(info.qos_profile, table) for info in infos]
        if not specs and table is not None:
            specs = [table]
        return [qos_of(spec) for spec in specs]

    def _register(self, topic: str, typename: str) -> str:
        """Add ``topic`` to the bag and the loss counts (idempotent); return its full name."""
        qos = self._offered_qos(topic)
        name = self._writer.add_topic(topic, typename, qos=qos)
        self._qos.setdefault(name, qos)
        self._types[name] = typename
        self.loss.add_topic(name)
        return name

    def _subscribe(self, topic: str, typename: str) -> None:
        name = self._register(topic, typename)
        reliable = self._offered_reliable(topic)
        if not reliable:
            self._best_effort.add(name)
        if reliable:
            qos = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                             reliability=ReliabilityPolicy.RELIABLE)
        else:
            qos = QoSProfile(depth=self._cfg["recorder.queue_depth"],
                             reliability=ReliabilityPolicy.BEST_EFFORT)
        write = self._writer_for(name)
        sub = self.create_subscription(_msg_class(typename), topic, write, qos, raw=True)
        self._subs.append((sub, name, write))

    def _resolve_pending(self) -> None:
        """Subscribe to pending topics that now have a publisher.

        A topic is subscribed once the graph shows a publisher of it (as ``ros2 bag record``
        does), so its reliability is chosen from what the publishers offer, however long
        their discovery takes (on a loaded machine it took more than the 1 s
        ``recorder.discovery_wait``, and a reliable topic was recorded best effort). A clutch
        topic has its known type; any other the type the graph advertises.
        """
        advertised = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            types = advertised.get(self.resolve_topic_name(topic))
            if not types or not self.count_publishers(self.resolve_topic_name(topic)):
                continue
            self._pending.remove(topic)
            typename = DEFAULT_TOPICS.get(topic, types[0])
            try:
                self._subscribe(topic, typename)
                self.get_logger().info(f"recording {topic} ({typename})")
            except (ClutchError, ImportError, AttributeError) as err:
                self.get_logger().error(f"cannot record {topic} ({typename}): {err}")
        if not self._pending and self._resolver is not None:
            self.destroy_timer(self._resolver)
            self._resolver = None

    # -- writing and splitting ------------------------------------------------------------
    def _new_part(self) -> BagWriter:
        path = self.output / f"part_{len(self.parts):04d}" if self._split else self.output
        self.parts.append(path)
        mcap = self._cfg["recorder.storage"] == "mcap"
        writer = BagWriter(path, storage=self._cfg["recorder.storage"],
                           namespace=self.get_namespace(),
                           chunk_interval=self._cfg["recorder.chunk_interval"] if mcap else None,
                           sync=self._cfg["recorder.fsync"]).open()
        for topic, typename in self._types.items():
            writer.add_topic(topic, typename, qos=self._qos.get(topic))
        self._part_bytes = 0
        self._part_start: int | None = None  # [ns] first stamp of the open part
        return writer

    def _rotate_if_due(self, stamp_ns: int) -> None:
        size, span = self._cfg["recorder.split_size"], self._cfg["recorder.split_duration"]
        if not (size or span):
            return
        if self._part_start is None:
            self._part_start = stamp_ns
            return
        if (size and self._part_bytes >= size) or \
                (span and interfaces.ns_to_s(stamp_ns - self._part_start) >= span):
            if not self._split:  # splitting switched on live: this bag stays as it is
                return
            self._finish(self._writer)
            self._writer = self._new_part()
            self._part_start = stamp_ns

    def _close_chunk_if_due(self) -> None:
        """Close the open chunk if it would be chunk_interval old before the next check."""
        self._writer.close_chunk_if_due(ahead=self._chunk_check)

    def _finish(self, writer: BagWriter) -> None:
        for topic, n in writer.close().items():
            self._closed_written[topic] = self._closed_written.get(topic, 0) + n

    def _writer_for(self, name: str):
        loss, clock = self.loss, self.get_clock()

        def write(data: bytes, info) -> None:
            gap = loss.received(name, info)
            stamp = clock.now().nanoseconds
            self._rotate_if_due(stamp)
            if gap:
                self._writer.mark_dropped(name, gap)
            self._writer.write_raw(name, stamp, data)
            self._part_bytes += len(data)
        return write

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Apply split and drain settings; splitting itself must be chosen at start."""
        for p in params:
            if p.name in ("recorder.split_size", "recorder.split_duration") and p.value \
                    and not self._split:
                return SetParametersResult(successful=False, reason=(
                    f"{p.name}: splitting is chosen at start (the output is then a directory "
                    "of parts); this recorder writes one bag"))
        for p in params:
            if p.name in LIVE:
                self._cfg[p.name] = p.value
        return SetParametersResult(successful=True)

    # -- reporting ------------------------------------------------------------------------
    @property
    def received(self) -> dict[str, int]:
        """Messages received per topic (absolute name) [messages]."""
        return self.loss.counts("received")

    @property
    def written(self) -> dict[str, int]:
        """Messages written per topic over every part [messages]."""
        out = dict(self._closed_written)
        if not self._writer.closed:
            for topic, n in self._writer.written.items():
                out[topic] = out.get(topic, 0) + n
        return out

    def _diagnose(self):
        written = self.written
        values: dict[str, Any] = {}
        for topic, stats in self.loss.topics.items():
            values[f"received{topic}"] = stats.received
            values[f"written{topic}"] = written.get(topic, 0)
            values[f"dropped{topic}"] = stats.dropped
            values[f"missed_at_start{topic}"] = stats.missed_at_start
        values.update(output=str(self.output), parts=len(self.parts),
                      loss_tracked=self.loss.tracked, waiting_for=",".join(self._pending))
        dropped = sum(s.dropped for s in self.loss.topics.values())
        if dropped:
            return "WARN", f"recording to {self.output}; {dropped} messages lost", values
        return "OK", f"recording to {self.output}", values

    def summary(self) -> dict:
        """Return per topic: received, written, dropped, missed_at_start [messages]."""
        written = self.written
        return {topic: {"received": s.received, "written": written.get(topic, 0),
                        "dropped": s.dropped, "missed_at_start": s.missed_at_start,
                        "unwritten_at_shutdown": self.unwritten.get(topic, 0),
                        "best_effort": topic in self._best_effort}
                for topic, s in self.loss.topics.items()}

    def drain(self, executor=None, quiet: float | None = None, limit: float | None = None,
              stop=lambda: False) -> int:
        """Write what DDS still queues for the recorder; return the messages taken.

        Takes from the subscriptions directly (:func:`clutch_ros.nodes.drain.drain`;
        ``executor`` is not spun, so no timer runs and the node's own ``/diagnostics`` stay
        silent) until none had a message for ``quiet`` [s] (``recorder.drain_quiet``),
        ``limit`` [s] (``recorder.drain_timeout``) passed or ``stop()`` is true. Call before
        :meth:`close` at shutdown.
        """
        quiet = self._cfg["recorder.drain_quiet"] if quiet is None else quiet
        limit = self._cfg["recorder.drain_timeout"] if limit is None else limit
        return drain([(sub, write) for sub, _, write in self._subs], quiet, limit, stop)

    def discard_queued(self, limit: float = DISCARD_LIMIT) -> int:
        """Take and count (not write) what is still queued; at most ``limit`` [s] long.

        The count goes into the summary (``unwritten_at_shutdown``) and the bag's
        ``clutch_ros.dropped``; sequence gaps among them are counted as usual.
        """
        end, total = time.monotonic() + limit, 0
        for sub, name, _ in self._subs:
            def count(data, info, name=name) -> None:
                gap = self.loss.received(name, info)
                if gap:
                    self._writer.mark_dropped(name, gap)
                self.unwritten[name] = self.unwritten.get(name, 0) + 1
                self._writer.mark_dropped(name, 1)

            while time.monotonic() < end and (n := take(sub, count)):
                total += n
        return total

    def close(self) -> dict[str, int]:
        """Finish the bag(s) (verifying counts) and return messages written per topic."""
        if self._writer.closed:
            return self.written
        self._writer.set_custom_data("clutch_ros.received", format_counts(self.received))
        self._writer.set_custom_data("clutch_ros.missed_at_start",
                                     format_counts(self.loss.counts("missed_at_start")))
        self._writer.set_custom_data("clutch_ros.loss_tracked", str(self.loss.tracked).lower())
        if self._split:
            self._writer.set_custom_data("clutch_ros.parts", str(len(self.parts)))
        self._finish(self._writer)
        written = self.written
        lost = {k: n - written.get(k, 0) - self.unwritten.get(k, 0)
                for k, n in self.received.items()
                if n != written.get(k, 0) + self.unwritten.get(k, 0)}
        if lost:
            self.get_logger().error(f"messages received but not written: {lost}")
        self.get_logger().info(f"recorder summary: {json.dumps(self.summary(), sort_keys=True)}")
        return written


def _run(args) -> int:
    """Spin the recorder until SIGINT/SIGTERM, then drain the DDS queues (bounded) and close."""
    signals: list[float] = []  # [s] monotonic time of each SIGINT/SIGTERM

    def on_signal(signum, frame):
        signals.append(time.monotonic())

    rclpy.init(args=[sys.argv[0], *args], signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, on_signal)  # from here on: a signal stops, never kills
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    try:
        try:
            node = RecorderNode()
            realtime = start_realtime(node)  # rt.* (nodes/realtime.py), like every node
        except (ClutchError, ValueError, ParameterException) as err:
            sys.stderr.write(f"{NAME}: error: {err}\n")
            return 2
        executor = make_executor("single")
        executor.add_node(node)
        while not signals:
            executor.spin_once(timeout_sec=0.1)
        drained = node.drain(stop=lambda: len(signals) > 1)  # a second signal: close now
        discarded = node.discard_queued()
        del realtime  # its /diagnostics timer lived as long as the spin
        node.close()
        node.get_logger().info(
            f"shutdown: {drained} queued messages written, {discarded} counted unwritten, "
            f"bag closed {time.monotonic() - signals[0]:.3f} s after the signal")
        executor.shutdown()
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros recorder``."""
    argv = list(sys.argv[1:] if args is None else args)
    if help_requested(argv):
        sys.stdout.write(format_help(NAME, __doc__, [*PARAMS, *REALTIME_PARAMS]))
        return 0
    return _run(argv)


if __name__ == "__main__":
    raise SystemExit(main())
