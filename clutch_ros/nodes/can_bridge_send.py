"""The can_bridge's send side: PressureCommand -> :class:`PumpCommandGate` -> PumpRequest frame.

:class:`PumpSender` holds what the command path and the PumpRequest cycle share: the gate
(in the bridge's :class:`~clutch_ros.nodes.can_bridge_state.BridgeState`), the command just
admitted and the ``pump_request`` report, behind one lock. Two threads use it: the executor
(:meth:`PumpSender.on_command` for each ``pressure_command``, :meth:`PumpSender.reconfigure`
for a live parameter change, :meth:`PumpSender.zero` at a halt) and the cycle thread
(:meth:`PumpSender.tick` every ``pump.period``, :mod:`clutch_ros.nodes.cycle`).
Each call takes the lock for the gate's decision, the frame's send and its report together,
so frames leave in the order the gate made them (the rolling counter advances by one on the
bus) and a report names the frame it follows.

Where commands come from (:meth:`PumpSender.subscribe`): on the wall clock the cycle thread
takes them (:class:`~clutch_ros.nodes.polled.PolledSubscription`) at each PumpRequest cycle,
just before the cycle's frame, which then carries the newest admitted target
(:meth:`PumpSender.cycle`): a command waits at most one ``pump.period`` for its frame, as on a
cyclic CAN message, and the executor no longer wakes ~100 times a second for commands (each
wake-up ~0.3 ms of CPU, ``python -m benchmarks.wakeup_probe``). On simulated time they stay
executor callbacks and every admitted command is answered by a frame at once (lock-step,
:mod:`clutch_ros.nodes.lockstep`), its report carrying the command's stamp. A report of a
frame that answers no command (the periodic frame, a rate-limit step, the watchdog) carries,
on simulated time, the stamp of the newest admitted command (its target is what the frame
follows), or stamp 0 before the first, with both torques 0: the rig keys a tick's answer on
(stamp, torques) of the command, and a periodic report stamped with the node clock matched
a command of that tick with zero torques before the bridge had admitted it (a tick counted
as answered while the bridge still refused commands from a publisher not yet in its graph).

Admission (before the gate's own checks): commands while the node is not active and from a
publisher other than ``pump.command_source`` are refused and counted (the cycle runs from
configure to cleanup, so commands that arrive while inactive are taken and counted too). A
frame that cannot be sent (link down) is logged at most every 5 s; the pump ECU's own request
timeout then takes it to 0 bar.
"""

from __future__ import annotations

import threading
import time
from collections import namedtuple
from collections.abc import Callable
from typing import Any

from clutch_msgs.msg import PressureCommand

from clutch_ros.canbus import CanError, PumpGateConfig
from clutch_ros.errors import ClutchError
from clutch_ros.interfaces import PRESSURE_COMMAND, stamp_to_s
from clutch_ros.nodes.can_bridge_state import BridgeState
from clutch_ros.nodes.convert import CdrCodec
from clutch_ros.nodes.diagnostics import LogThrottle
from clutch_ros.nodes.polled import PolledSubscription
from clutch_ros.nodes.qos import sensor_qos

__all__ = ["SEND_TIMEOUT", "PumpSender"]

SEND_TIMEOUT = 0.005  # [s] a pump request never blocks its thread longer
#: PressureCommand's leaves in CDR order (the fields of a command as :meth:`on_command` reads
#: them, with ``.`` as ``_``, and of the report it writes)
COMMAND_FIELDS = ("header.stamp.sec", "header.stamp.nanosec", "header.frame_id", "pressure",
                  "requested_torque", "predicted_torque", "limited", "reason", "trim_pressure")


class PumpSender:
    """The bridge's gate, its frames and their reports, shared by two threads (module doc).

    ``node``: the bridge (its logger, clock and context); ``state``: its state (gate, bus,
    command sources, ``active``); ``on_stamp(stamp)`` [s] is called with the stamp of every
    command from the configured source (the node's simulated-time floor).
    """

    def __init__(self, node, state: BridgeState, on_stamp: Callable[[float], None]) -> None:
        self._node, self._state, self._on_stamp = node, state, on_stamp
        self._lock = threading.Lock()
        self._command = None  # the command admitted (its fields), reported with its frame
        self._admitted_stamp = (0, 0)  # (sec, nanosec) of the newest admitted command
        # commands are read from, and reports written as, CDR bytes (no message object: the
        # rclpy conversions cost ~0.1 ms per command on the executor)
        codec = CdrCodec(PressureCommand)
        if codec.names != COMMAND_FIELDS:
            raise ClutchError(f"PressureCommand fields {codec.names} changed")
        self._decode, self._encode = codec.decode, codec.encode
        self._fields: Any = namedtuple(  # type: ignore[misc]
            "Command", [n.replace(".", "_") for n in COMMAND_FIELDS])
        self._warn = LogThrottle(5.0)
        #: the ``pump_request`` publisher (configure makes it, cleanup removes it)
        self.publisher: Any = None
        #: use_sim_time: every admitted command answered by a frame, reports keep its stamp
        self.sim_time = False
        self._polled: PolledSubscription | None = None  # wall clock: taken by cycle()
        self._subscription: Any = None  # simulated time: an executor callback

    def subscribe(self, polled: bool) -> str:
        """Subscribe to ``pressure_command`` (configure); return its resolved topic name.

        ``polled``: taken by :meth:`cycle` (the wall clock's cycle thread), else an executor
        callback (:meth:`on_command`, simulated time).
        """
        name, qos = PRESSURE_COMMAND.name, sensor_qos()
        if polled:
            self._polled = PolledSubscription(self._node, PressureCommand, name, qos, raw=True)
            return self._polled.topic_name
        self._subscription = self._node.create_subscription(
            PressureCommand, name, self.on_command, qos, raw=True)
        return self._subscription.topic_name

    def unsubscribe(self) -> None:
        """Remove the subscription (cleanup; after the cycle stopped)."""
        if self._polled is not None:
            self._polled.destroy()
        if self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
        self._polled = self._subscription = None

    def cycle(self) -> None:
        """Admit the commands taken now, then send the frame: the PumpRequest cycle's job.

        Runs from configure to cleanup; the frame only while active (:meth:`tick`).
        """
        polled = self._polled
        if polled is not None:
            for item in polled.take():
                self.on_command(item.message, item.info, immediate=False)
        self.tick()

    def on_command(self, raw: bytes, info, immediate: bool = True) -> None:
        """Admit a ``pressure_command`` (its CDR bytes; ``info``: its message info).

        ``immediate``: a changed target is sent at once (the gate's immediate frame), else
        by the next :meth:`tick`, which reports the command.
        """
        msg = self._fields._make(self._decode(raw))
        st = self._state
        gate = st.gate
        assert gate is not None  # the subscription is made by configure, after the gate
        with self._lock:
            st.sources.count_sequence(info)
            kind, reason = ("inactive", "command refused: can_bridge is not active") \
                if not st.active else ("source", st.sources.check(info))
            if reason is not None:
                gate.refuse(kind, reason)
                return
            stamp = stamp_to_s(msg.header_stamp_sec, msg.header_stamp_nanosec)
            self._on_stamp(stamp)
            if not immediate:
                if gate.admit(msg.pressure, stamp if stamp > 0.0 else None) is not None:
                    self._command = msg  # reported with the next frame
                return
            admitted = gate.commands
            out = gate.submit(msg.pressure, stamp if stamp > 0.0 else None)
            if out is None and self.sim_time and gate.commands != admitted:
                out = gate.tick()  # simulated time: every admitted command answered by a frame
            self._send(out, msg if gate.commands != admitted else None)

    def tick(self) -> None:
        """Send the PumpRequest cycle's frame (the gate's periodic one, watchdog checked)."""
        gate = self._state.gate
        assert gate is not None  # the cycle runs while active, so configured
        with self._lock:
            if self._state.active:  # (a halt in progress sends its own 0 bar frame)
                self._send(gate.tick())

    def zero(self, why: str) -> None:
        """Send a 0 bar frame at once (``why``: the reason, e.g. ``"shutdown"``) and keep 0 bar."""
        gate = self._state.gate
        assert gate is not None  # (with the bus)
        with self._lock:
            self._send(gate.zero(why), timeout=0.05)

    def reconfigure(self, config: PumpGateConfig) -> None:
        """Apply new gate limits from the next frame on (:meth:`PumpCommandGate.reconfigure`)."""
        gate = self._state.gate
        if gate is not None:
            with self._lock:
                gate.reconfigure(config)

    def _send(self, out, command=None, timeout: float = SEND_TIMEOUT) -> None:
        """Send the gate's frame (if any); report it on pump_request when new or changed.

        ``command``: the PressureCommand just admitted (reported with the next frame). Called
        with the lock held.
        """
        if command is not None:
            self._command = command
        if out is None:
            return
        st, pub = self._state, self.publisher
        assert st.bus is not None and pub is not None  # a frame: the bus is open
        try:
            st.bus.send(out.frame, timeout=timeout)
        except CanError as err:  # link down: the pump's own timeout takes it to 0 bar
            if self._warn.ready():
                self._node.get_logger().warning(f"pump request not sent: {err}")
        command, self._command = self._command, None
        if command is None and (out.pressure, out.reason) == st.last_report:
            return
        st.last_report = (out.pressure, out.reason)
        if command is not None and self.sim_time:  # the command's stamp (nodes/lockstep)
            sec, nanosec = command.header_stamp_sec, command.header_stamp_nanosec
            self._admitted_stamp = (sec, nanosec)
        elif self.sim_time:  # answers no command: the newest admitted one's (module doc)
            sec, nanosec = self._admitted_stamp
        else:  # the ROS clock without use_sim_time is the system clock
            sec, nanosec = divmod(time.time_ns(), 10**9)
        applied = self._encode(sec, nanosec, "", float(out.pressure),
                               command.requested_torque if command else 0.0,
                               command.predicted_torque if command else 0.0,
                               bool(out.limited), out.reason, 0.0)
        try:
            pub.publish(applied)
        except Exception:  # noqa: BLE001 - after SIGINT the context is gone; the frame went out
            if self._node.context.ok():
                raise
