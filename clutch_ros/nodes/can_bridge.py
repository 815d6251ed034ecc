"""The ``can_bridge`` node: rig CAN frames <-> typed topics, and pump pressure requests.

Receive: a python-can bus (any interface, chosen by the ``can.*`` parameters) is read on a
python-can Notifier thread. Each frame takes one straight path: the assembler decodes it into
the live sample (:mod:`clutch_ros.canbus`), the pacer decides, and the sample becomes the
``rig_state`` message (:func:`clutch_ros.rigstate.fill_msg`). ``rig_state`` is published,
stamped with the newest contributing frame's bus
timestamp (not the publish time), only when new frames arrived: at once when the
``bridge.publish_on`` frame (the end of the rig's cycle) arrives, at most ``bridge.rate``
(:class:`~clutch_ros.canbus.counters.PublishPacer`), or on a ``bridge.rate`` timer when that
is empty. Stale signal groups are flagged in ``stale_mask`` and diagnosed; an idle bus warns
once. ``bridge.publish_raw`` publishes every frame on ``can_frames``. Our own frames looped
back by the interface (udp_multicast) are removed by the bus, never decoded.

Send: ``pressure_command`` goes through :class:`clutch_ros.canbus.PumpCommandGate` (NaN,
negative, huge -> a frame within limits; rate limit; 0 bar when no command is admitted for
``pump.watchdog_timeout``). Admission: a command stamped more than ``pump.watchdog_timeout``
ago or more than ``pump.future_tolerance`` ahead of this node's clock (simulated time when
``use_sim_time``), older than the last admitted one, or unstamped (unless
``pump.accept_unstamped``) is refused and counted. ``pump.command_source`` (a node name,
``controller`` or ``/rig1/controller``) admits that node's commands only: rclpy does not tell
a subscriber the sender's name, but it gives the publisher's GID with each message
(``MessageInfo["publisher_gid"]``), and the graph (``get_publishers_info_by_topic``) maps
GIDs to node names; a command from an unknown GID is refused until the graph names it. More
than one publisher on ``pressure_command`` is an ERROR on ``/diagnostics`` naming them.
The PumpRequest (rolling counter + CRC-8) is sent every ``pump.period`` (the DBC cycle, the
latest admitted command) plus at most one immediate frame per period when the request changes,
so commands at any rate never make a backlog; what was applied and why is published on
``pump_request`` with each frame after a new command and whenever it changes.

Stopping: SIGINT/SIGTERM (rclpy turns them into a shutdown) and ``close`` send a last 0 bar
PumpRequest at once. A bridge killed without a chance to run (SIGKILL, power loss) sends
nothing more; the pump ECU then goes to 0 bar on its own request timeout: ``params/rig.dbc``
requires it of the ECU for a PumpRequest missing for more than 100 ms (the simulated rig's
pump does so, raising ``PumpSts_FltReqTimeout``).

Bus errors: error frames are counted; bus-off or an unplugged adapter takes the link down and
it is reopened with back-off, reported on ``/diagnostics`` (never a crash).
``input.log_file`` replays a Vector ASC/BLF (or any python-can log) through the same decode
path instead of a bus, at recorded timing (``input.realtime``) or as fast as possible; stamps
are shifted so that the log's first frame is stamped with the start time.
"""

from __future__ import annotations

import threading
import time

import can
from clutch_msgs.msg import CanFrame, PressureCommand, RigState
from rclpy.node import Node

from clutch_ros.canbus import (
    BusConfig,
    CanError,
    LogSource,
    PumpCommandGate,
    PumpGateConfig,
    ReconnectingBus,
    RigDatabase,
)
from clutch_ros.canbus import RigStateAssembler as Assembler
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.nodes.can_diagnostics import bridge_status
from clutch_ros.nodes.common import (
    Diagnostics,
    LogThrottle,
    ParamSpec,
    declare_params,
    reliable_qos,
    run_node,
    sensor_qos,
)
from clutch_ros.nodes.convert import can_frame_to_ros, rig_state_to_ros

NAME = "can_bridge"
IDLE_TIMEOUT = 1.0  # [s] no new rig frame for this long: one warning
SEND_TIMEOUT = 0.005  # [s] a pump request never blocks the executor longer
#: pressure_command queue: only the latest command matters, so a flood never queues a
#: backlog; commands overwritten in it are counted from the publishers' sequence numbers
COMMAND_DEPTH = 5
FLUSH_PERIOD = 0.05  # [s] with publish_on: a frame held back by bridge.rate goes out then
PARAMS = [
    ParamSpec("can.interface", "udp_multicast", "python-can interface (socketcan, vector, "
              "pcan, kvaser, udp_multicast, virtual, ...)"),
    ParamSpec("can.channel", "239.74.163.2", "interface channel (can0, 0, PCAN_USBBUS1, a "
              "multicast group ...)"),
    ParamSpec("can.port", 43113, "UDP port (udp_multicast only)", "", 1, 65535),
    ParamSpec("can.bitrate", 0, "bit rate; 0 keeps the interface default", "bit/s", 0,
              20_000_000),
    ParamSpec("can.fd", False, "open the bus in CAN FD mode"),
    ParamSpec("can.receive_own_messages", False, "receive frames this node sends"),
    ParamSpec("can.filters", [""], "acceptance filters 'ID:MASK[:x]'; empty: all frames"),
    ParamSpec("bridge.dbc_file", "", "rig DBC; empty: the package's params/rig.dbc"),
    ParamSpec("bridge.rate", 200.0, "rig_state publishing rate (at most)", "Hz", 1.0, 5000.0),
    ParamSpec("bridge.publish_on", "RigSpeed", "DBC frame whose arrival publishes rig_state; "
              "empty: a bridge.rate timer"),
    ParamSpec("bridge.publish_raw", False, "publish every frame on can_frames"),
    ParamSpec("pump.max_pressure", 40e5, "largest pressure ever requested", "Pa", 1e4, 60e5),
    ParamSpec("pump.rate_limit", 400e5, "maximum rise of the requested pressure", "Pa/s",
              1e3, 1e10),
    ParamSpec("pump.watchdog_timeout", 0.2, "no pressure_command for this long -> 0 bar",
              "s", 0.005, 60.0),
    ParamSpec("pump.period", 0.01, "PumpRequest repetition period (the DBC cycle)", "s",
              0.001, 1.0),
    ParamSpec("pump.future_tolerance", 0.05, "pressure_command stamped further ahead of "
              "this node's clock than this is refused", "s", 0.0, 10.0),
    ParamSpec("pump.accept_unstamped", False, "admit pressure_command without a stamp"),
    ParamSpec("pump.command_source", "", "admit pressure_command from this node only "
              "(name or fully qualified name); empty: any publisher"),
    ParamSpec("input.log_file", "", "replay this CAN log (.asc, .blf, ...) instead of a bus"),
    ParamSpec("input.realtime", True, "log replay at recorded timing (false: fast)"),
    ParamSpec("input.wait_for_subscribers", 0, "log replay starts once rig_state has this many "
              "subscribers", "", 0, 1000),
]


class CanBridgeNode(Node):
    """Rig CAN <-> ROS bridge (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        cfg = self._cfg = declare_params(self, PARAMS)
        self._send_warn = LogThrottle(5.0)
        self._db = RigDatabase(cfg["bridge.dbc_file"] or None)
        self._trigger = self._db.frame(cfg["bridge.publish_on"]).key \
            if cfg["bridge.publish_on"] else None
        self._assembler = Assembler(self._db, socketcan_error_frames=cfg["can.interface"]
                                    == "socketcan")
        rig_keys = frozenset(self._db.frame(g.message).key for g in self._assembler.groups)
        self._gate = PumpCommandGate(time.monotonic, PumpGateConfig(
            max_pressure=cfg["pump.max_pressure"], rate_limit_up=cfg["pump.rate_limit"],
            watchdog_timeout=cfg["pump.watchdog_timeout"],
            future_tolerance=cfg["pump.future_tolerance"],
            accept_unstamped=cfg["pump.accept_unstamped"]),
            stamp_clock=lambda: self.get_clock().now().nanoseconds * 1e-9)
        self._command = None  # the latest admitted PressureCommand, until reported
        self._sources = CommandSources(self, cfg["pump.command_source"])
        self._pump_key, self._foreign_requests = self._gate.codec.spec.key, 0
        self._pacer = PublishPacer(cfg["bridge.rate"], self._trigger, rig_keys)
        self._offset = None  # epoch - bus time [s], for adapters with relative clocks
        self._last_stamp = self._last_report = self._stale = None
        self._published = self._stale_reports = 0
        self._last_new, self._idle_warned = time.monotonic(), False
        self._rig_pub = self.create_publisher(RigState, "rig_state", sensor_qos())
        self._cmd_pub = self.create_publisher(PressureCommand, "pump_request", reliable_qos())
        self._raw_pub = (self.create_publisher(CanFrame, "can_frames", reliable_qos(1000))
                         if cfg["bridge.publish_raw"] else None)
        self._stop, self._lock = threading.Event(), threading.Lock()
        self._bus = self._notifier = self._log_thread = self._source = None
        if cfg["input.log_file"]:
            self._start_log(cfg["input.log_file"], cfg["input.realtime"])
        else:
            self._sources.topic = self.create_subscription(
                PressureCommand, "pressure_command", self._on_command,
                reliable_qos(COMMAND_DEPTH)).topic_name
            self.create_timer(cfg["pump.period"], lambda: self._send(self._gate.tick()))
            period = 1.0 / cfg["bridge.rate"]  # with publish_on: only flushes held frames
            self.create_timer(period if self._trigger is None else max(period, FLUSH_PERIOD),
                              lambda: self._publish_latest(self._pacer.flush))
            self._start_bus()
        self._diag = Diagnostics(self, self._diagnose)

    # -- receive --------------------------------------------------------------------------
    def _start_bus(self) -> None:
        config = BusConfig.from_params(self._cfg)
        self._bus = ReconnectingBus(config, on_event=self._on_link_event)
        self._notifier = can.Notifier(self._bus, [self._on_frame], timeout=0.1)
        self.get_logger().info(f"CAN {config.describe()} open; decoding with {self._db.path}")

    def _on_link_event(self, event) -> None:  # the bus rate-limits its own log lines
        if event.new == "closed":
            return
        if event.new == "up":
            self.get_logger().info(f"CAN link {event.old} -> up", throttle_duration_sec=10.0)
        else:
            self.get_logger().warning(f"CAN link {event.old} -> {event.new}: {event.reason}",
                                      throttle_duration_sec=10.0)

    def _on_frame(self, frame) -> None:
        """Notifier thread: frame -> live sample -> (pacer) -> rig_state, in one pass."""
        try:
            key = self._assembler.feed(frame)
            if self._raw_pub is not None:
                self._raw_pub.publish(can_frame_to_ros(frame, self._offset or 0.0))
            if key is None:
                return
            if key == self._pump_key:  # ours never come back (the bus removes echoes)
                self._foreign_requests += 1
            self._publish_latest(self._pacer.on_frame, key)
        except Exception as err:  # noqa: BLE001 - counted; the Notifier thread must live
            self._assembler.on_error(err)

    def _start_log(self, path: str, realtime: bool) -> None:

        source = self._source = LogSource(path, realtime=realtime)
        source.check()  # a bad file fails the start with a clear message

        def replay():
            while self.count_subscribers("rig_state") < self._cfg["input.wait_for_subscribers"]:
                if self._stop.wait(0.05):
                    return
            try:
                for sample in source.samples(self._assembler, 1.0 / self._cfg["bridge.rate"],
                                             self._stop):
                    if self._offset is None and source.first_time is not None:
                        self._offset = time.time() - source.first_time
                    self._publish(sample)
                self.get_logger().info(f"log {path} done: {source.frames_read} frames, "
                                       f"{self._published} rig_state published")
            except Exception as err:  # noqa: BLE001 - report, never crash the node
                self.get_logger().error(f"log replay stopped: {err}")

        self._log_thread = threading.Thread(target=replay, name="can_log", daemon=True)
        self._log_thread.start()

    def _publish_latest(self, decide, *args) -> None:
        """Publish the latest signals if ``decide(*args, now)`` (the pacer) and they are new.

        Runs on the Notifier thread (frames) and the executor (timer), hence the lock.
        """
        with self._lock:
            if not decide(*args, time.monotonic()):
                return
            newest = self._assembler.newest_time
            if newest is not None and self._offset is None:  # relative clocks -> the epoch
                skew = time.time() - newest
                self._offset = skew if abs(skew) > 3600.0 else 0.0
            if newest is None or not self._publish(
                    self._assembler.snapshot(time.time() - self._offset)):
                self._pacer.refund()

    def _publish(self, sample) -> bool:
        if sample.stamp is None or sample.stamp == self._last_stamp:
            return False
        self._last_stamp, self._last_new, self._stale = sample.stamp, time.monotonic(), \
            sample.stale
        self._stale_reports += bool(sample.stale_mask)
        self._rig_pub.publish(rig_state_to_ros(sample, self._offset or 0.0))
        self._published += 1
        return True

    # -- send -----------------------------------------------------------------------------
    def _on_command(self, msg, info) -> None:
        self._sources.count_sequence(info)
        source = self._sources.check(info)
        if source is not None:
            self._gate.refuse("source", source)
            return
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        admitted = self._gate.commands
        out = self._gate.submit(msg.pressure, stamp if stamp > 0.0 else None)
        if self._gate.commands != admitted:
            self._command = msg
        if out is not None:
            self._send(out)

    def _send(self, out) -> None:
        try:
            self._bus.send(out.frame, timeout=SEND_TIMEOUT)
        except CanError as err:  # link down: the pump's own timeout takes it to 0 bar
            if self._send_warn.ready():
                self.get_logger().warning(f"pump request not sent: {err}")
        command, self._command = self._command, None
        if command is None and (out.pressure, out.reason) == self._last_report:
            return
        self._last_report = (out.pressure, out.reason)
        applied = PressureCommand()
        applied.header.stamp = self.get_clock().now().to_msg()
        applied.pressure = float(out.pressure)
        applied.requested_torque = command.requested_torque if command else 0.0
        applied.predicted_torque = command.predicted_torque if command else 0.0
        applied.limited, applied.reason = bool(out.limited), out.reason
        self._cmd_pub.publish(applied)

    # -- health ---------------------------------------------------------------------------
    def _diagnose(self):
        if self._bus is not None:  # idle bus: one warning when it goes quiet, one info back
            idle = time.monotonic() - self._last_new
            if idle > IDLE_TIMEOUT and not self._idle_warned:
                self._idle_warned = True
                self.get_logger().warning(f"no new rig frames for {idle:.1f} s; rig_state "
                                          "paused")
            elif idle <= IDLE_TIMEOUT and self._idle_warned:
                self._idle_warned = False
                self.get_logger().info("rig frames again; rig_state resumed")
        extra = {"rig_state_published": self._published, "stale_samples": self._stale_reports,
                 "stale_groups": ", ".join(self._stale or []),
                 "foreign_pump_requests": self._foreign_requests}
        if self._source is None:
            extra.update(self._sources.diagnose())
        if self._source is not None:
            extra.update(log_file=str(self._source.path), log_frames=self._source.frames_read,
                         log_done=not self._log_thread.is_alive())
        return bridge_status(self._assembler, self._bus, self._gate, self._pacer.fallback,
                             extra)

    def close(self) -> None:
        """Stop the receive threads, send a last 0 bar request and close the bus."""
        self._stop.set()
        if self._notifier is not None:
            self._notifier.stop()
        if self._log_thread is not None:
            self._log_thread.join(timeout=2.0)
        if self._bus is not None:
            try:
                self._bus.send(self._gate.zero("shutdown").frame, timeout=0.05)
            except Exception:  # noqa: BLE001 - best effort on shutdown
                pass
            self._bus.shutdown()


class CommandSources:
    """Who publishes ``pressure_command``: publisher GIDs -> node names, from the ROS graph.

    ``wanted`` is the admitted source (a node name or fully qualified name; empty: any).
    :meth:`check` takes a message's ``MessageInfo`` and returns None to admit it, else why it
    is refused. The GID table is refreshed from ``get_publishers_info_by_topic`` when an
    unknown GID arrives (at most every ``REFRESH`` s) and by :meth:`diagnose` (1 Hz).
    """

    REFRESH = 0.2  # [s]

    def __init__(self, node: Node, wanted: str) -> None:
        self.node, self.wanted, self.topic = node, wanted.strip(), "pressure_command"
        self._names: dict[bytes, str] = {}
        self._next_refresh = 0.0
        self.publishers: list[str] = []
        self._sequence: dict[bytes, int] = {}  # publisher GID -> last sequence number
        #: commands that never reached the callback (overwritten in the queue), counted
        #: from the gaps in each publisher's sequence numbers
        self.superseded = 0

    def count_sequence(self, info) -> None:
        """Count the commands a publisher sent that this subscription never saw."""
        gid = info.get("publisher_gid") if isinstance(info, dict) else None
        number = info.get("publication_sequence_number") if isinstance(info, dict) else None
        if not gid or number is None:
            return
        key = bytes(gid["data"])
        last = self._sequence.get(key)
        if last is not None and number > last + 1:
            self.superseded += number - last - 1
        if len(self._sequence) < 64 or key in self._sequence:  # bounded
            self._sequence[key] = number

    def _refresh(self) -> None:
        infos = self.node.get_publishers_info_by_topic(self.topic)
        self._names = {bytes(i.endpoint_gid): _fqn(i.node_namespace, i.node_name)
                       for i in infos}
        self.publishers = sorted(self._names.values())
        self._next_refresh = time.monotonic() + self.REFRESH

    def check(self, info) -> str | None:
        """Return None when a message with MessageInfo ``info`` is admitted, else why not."""
        if not self.wanted:
            return None
        gid = (info or {}).get("publisher_gid") if isinstance(info, dict) else None
        if not gid:
            return "command refused: this rmw gives no publisher GID to check the source"
        key = bytes(gid["data"])
        name = self._names.get(key)
        if name is None and time.monotonic() >= self._next_refresh:
            self._refresh()
            name = self._names.get(key)
        if name is None:
            return "command refused: publisher not (yet) in the ROS graph"
        if name == self.wanted or name.rsplit("/", 1)[-1] == self.wanted:
            return None
        return f"command refused: from {name}, pump.command_source is {self.wanted}"

    def diagnose(self) -> dict:
        """Refresh the table; return the publishers as diagnostic values."""
        self._refresh()
        return {"commands_superseded": self.superseded,
                "command_publishers": ", ".join(self.publishers),
                "command_publisher_count": len(self.publishers),
                "command_source": self.wanted or "(any)"}


def _fqn(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros can_bridge``; bad settings: one line, exit 2."""
    return run_node(NAME, __doc__, PARAMS, CanBridgeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
