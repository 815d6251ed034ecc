"""The ``can_bridge`` node: rig CAN frames <-> typed topics, and pump pressure requests.

Receive: a python-can bus (any interface: socketcan, vector, pcan, kvaser, udp_multicast,
virtual ...) is read on a python-can Notifier thread; frames in the DBC are decoded
(:mod:`clutch_ros.canbus`) and ``rig_state`` is published at ``bridge.rate`` from the latest
signals, stamped with the newest contributing frame's bus timestamp (not the publish time),
only when new frames arrived (an idle bus publishes nothing and warns once, not per sample).
Signal groups older than their maximum age are flagged in ``stale_mask`` and diagnosed.
``bridge.publish_raw`` publishes every frame on ``can_frames``.

Send: ``pressure_command`` goes through :class:`clutch_ros.canbus.PumpCommandGate`: NaN,
negative and huge commands give a frame within limits, the step is rate limited, and when
commands stop for ``pump.watchdog_timeout`` the request goes to 0 bar. The request frame
(rolling counter + CRC-8) is repeated every ``pump.period``; what was applied and why is
published on ``pump_request`` (PressureCommand).

Bus errors: error frames are counted; bus-off or an unplugged adapter takes the link down and
it is reopened with exponential back-off, reported on ``/diagnostics`` (never a crash).
``input.log_file`` replays a Vector ASC/BLF (or any python-can log) through the same decode
path instead of a live bus, at recorded timing (``input.realtime``) or as fast as possible;
log timestamps are shifted so that the first frame is stamped with the start time.
"""

from __future__ import annotations

import math
import threading
import time

from rclpy.node import Node

from clutch_ros.nodes.common import (
    Diagnostics,
    ParamSpec,
    declare_params,
    reliable_qos,
    run_node,
    sec_to_stamp,
    sensor_qos,
)

NAME = "can_bridge"
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
    ParamSpec("bridge.rate", 200.0, "rig_state publishing rate", "Hz", 1.0, 5000.0),
    ParamSpec("bridge.publish_raw", False, "publish every frame on can_frames"),
    ParamSpec("pump.max_pressure", 40e5, "largest pressure ever requested", "Pa", 1e4, 60e5),
    ParamSpec("pump.rate_limit", 400e5, "maximum rise of the requested pressure", "Pa/s",
              1e3, 1e10),
    ParamSpec("pump.watchdog_timeout", 0.2, "no pressure_command for this long -> 0 bar",
              "s", 0.005, 60.0),
    ParamSpec("pump.period", 0.01, "PumpRequest repetition period", "s", 0.001, 1.0),
    ParamSpec("input.log_file", "", "replay this CAN log (.asc, .blf, ...) instead of a bus"),
    ParamSpec("input.realtime", True, "log replay at recorded timing (false: fast)"),
]


class CanBridgeNode(Node):
    """Rig CAN <-> ROS bridge (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        from clutch_msgs.msg import CanFrame, PressureCommand, RigState

        from clutch_ros.canbus import (
            PumpCommandGate,
            PumpGateConfig,
            RigDatabase,
            RigStateAssembler,
        )

        cfg = self._cfg = declare_params(self, PARAMS)
        self._db = RigDatabase(cfg["bridge.dbc_file"] or None)
        self._assembler = RigStateAssembler(
            self._db, socketcan_error_frames=cfg["can.interface"] == "socketcan")
        self._gate = PumpCommandGate(time.monotonic, PumpGateConfig(
            max_pressure=cfg["pump.max_pressure"], rate_limit_up=cfg["pump.rate_limit"],
            watchdog_timeout=cfg["pump.watchdog_timeout"]))
        self._offset = None  # epoch - bus time [s], for adapters with relative clocks
        self._last_stamp = None
        self._published = self._idle_warned = 0
        self._stale_reports = 0
        self._rig_pub = self.create_publisher(RigState, "rig_state", sensor_qos())
        self._cmd_pub = self.create_publisher(PressureCommand, "pump_request", reliable_qos())
        self._raw_pub = (self.create_publisher(CanFrame, "can_frames", reliable_qos(1000))
                         if cfg["bridge.publish_raw"] else None)
        self._stop = threading.Event()
        self._bus = self._notifier = self._log_thread = None
        if cfg["input.log_file"]:
            self._start_log(cfg["input.log_file"], cfg["input.realtime"])
        else:
            self._start_bus()
            self.create_subscription(PressureCommand, "pressure_command", self._on_command,
                                     reliable_qos())
            self.create_timer(cfg["pump.period"], lambda: self._send(self._gate.tick()))
            self.create_timer(1.0 / cfg["bridge.rate"], self._publish_live)
        self._diag = Diagnostics(self, self._diagnose)

    # -- receive --------------------------------------------------------------------------
    def _start_bus(self) -> None:
        import can

        from clutch_ros.canbus import BusConfig, ReconnectingBus

        cfg = self._cfg
        extra = {"port": cfg["can.port"]} if cfg["can.interface"] == "udp_multicast" else {}
        config = BusConfig(interface=cfg["can.interface"], channel=cfg["can.channel"],
                           bitrate=cfg["can.bitrate"] or None, fd=cfg["can.fd"] or None,
                           receive_own_messages=cfg["can.receive_own_messages"],
                           can_filters=[f for f in cfg["can.filters"] if f] or None,
                           extra=extra)
        self._bus = ReconnectingBus(config, on_event=self._on_link_event)
        listeners = [self._assembler] + ([self._publish_raw] if self._raw_pub else [])
        self._notifier = can.Notifier(self._bus, listeners, timeout=0.1)
        self.get_logger().info(f"CAN {config.describe()} open; decoding with {self._db.path}")

    def _on_link_event(self, event) -> None:
        log = self.get_logger().info if event.new == "up" else self.get_logger().warning
        log(f"CAN link {event.old} -> {event.new}: {event.reason}")

    def _start_log(self, path: str, realtime: bool) -> None:
        from clutch_ros.canbus import LogSource

        source = LogSource(path, realtime=realtime)
        source.check()  # a bad file fails the start with a clear message

        def replay():
            try:
                for sample in source.samples(self._assembler, 1.0 / self._cfg["bridge.rate"],
                                             self._stop):
                    if self._offset is None and sample.stamp is not None:
                        self._offset = time.time() - sample.stamp
                    self._publish(sample)
                self.get_logger().info(f"log {path} done: {source.frames_read} frames, "
                                       f"{self._published} rig_state published")
            except Exception as err:  # noqa: BLE001 - report, never crash the node
                self.get_logger().error(f"log replay stopped: {err}")

        self._log_thread = threading.Thread(target=replay, name="can_log", daemon=True)
        self._log_thread.start()

    def _publish_raw(self, frame) -> None:
        from clutch_msgs.msg import CanFrame

        msg = CanFrame()
        sec_to_stamp(frame.timestamp + (self._offset or 0.0), msg.header.stamp)
        msg.id, msg.is_rtr = frame.arbitration_id, frame.is_remote_frame
        msg.is_extended, msg.is_error = frame.is_extended_id, frame.is_error_frame
        msg.dlc = min(frame.dlc, 255)
        msg.data = list(bytes(frame.data[:8]).ljust(8, b"\0"))
        self._raw_pub.publish(msg)

    def _publish_live(self) -> None:
        newest = self._assembler.newest_time
        if newest is None:
            return
        if self._offset is None:  # relative adapter clocks are mapped onto the epoch
            skew = time.time() - newest
            self._offset = skew if abs(skew) > 3600.0 else 0.0
        self._publish(self._assembler.snapshot(time.time() - self._offset))

    def _publish(self, sample) -> None:
        from clutch_msgs.msg import RigState

        if sample.stamp is None or sample.stamp == self._last_stamp:
            if self._last_stamp is not None and not self._idle_warned:
                self._idle_warned = 1
                self.get_logger().warning("no new rig frames; rig_state paused")
            return
        self._last_stamp, self._idle_warned = sample.stamp, 0
        if sample.stale_mask:
            self._stale_reports += 1
        msg = RigState()
        sec_to_stamp(sample.stamp + (self._offset or 0.0), msg.header.stamp)
        msg.header.frame_id = "clutch"
        for name in ("actuating_pressure", "lamella_temperature", "oil_temperature",
                     "input_speed", "output_speed", "slip_speed", "measured_torque",
                     "torque_request", "pump_current"):
            setattr(msg, name, float(getattr(sample, name)))
        msg.has_measured_torque = bool(sample.has_measured_torque
                                       and math.isfinite(sample.measured_torque))
        msg.ff_voltages = [float(v) for v in sample.ff_voltages]
        msg.wheel_speeds = [float(v) for v in sample.wheel_speeds]
        msg.stale_mask = int(sample.stale_mask)
        self._rig_pub.publish(msg)
        self._published += 1

    # -- send -----------------------------------------------------------------------------
    def _on_command(self, msg) -> None:
        self._send(self._gate.submit(msg.pressure), msg)

    def _send(self, out, command=None) -> None:
        from clutch_msgs.msg import PressureCommand

        from clutch_ros.canbus import CanError

        try:
            self._bus.send(out.frame)
        except CanError as err:  # link down: the pump's own timeout takes it to 0 bar
            self.get_logger().warning(f"pump request not sent: {err}", throttle_duration_sec=5.0)
        if command is not None or out.limited:
            applied = PressureCommand()
            applied.header.stamp = self.get_clock().now().to_msg()
            applied.pressure = float(out.pressure)
            applied.requested_torque = command.requested_torque if command else 0.0
            applied.predicted_torque = command.predicted_torque if command else 0.0
            applied.limited, applied.reason = bool(out.limited), out.reason
            self._cmd_pub.publish(applied)

    # -- health ---------------------------------------------------------------------------
    def _diagnose(self):
        from clutch_ros.nodes.can_diagnostics import bridge_status

        return bridge_status(self._assembler, self._bus, self._gate, self._published,
                             self._stale_reports)

    def close(self) -> None:
        """Stop the Notifier/log thread, send a last 0 bar request and close the bus."""
        self._stop.set()
        if self._notifier is not None:
            self._notifier.stop()
        if self._bus is not None:
            try:
                self._bus.send(self._gate.submit(0.0).frame)
            except Exception:  # noqa: BLE001 - best effort on shutdown
                pass
            self._bus.shutdown()


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros can_bridge``."""
    return run_node(NAME, __doc__, PARAMS, CanBridgeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
