"""Lock-step for the simulated rig: it publishes ``/clock`` and waits for the chain to answer.

With ``rig.lockstep`` the ``rig_sim`` node does not keep real time: it is the clock of the
ROS graph, and every node of the chain runs with ``use_sim_time`` (``clutch demo
--lockstep``). Every ``rig.lockstep_period`` (a sync tick ``T``, a whole number of plant
steps; default 10 ms, the controller's, the bridge's rig_state and the PumpRequest period)
:class:`LockStepSync` does, from the simulation thread:

1. publish ``/clock`` = ``T`` (``rosgraph_msgs/Clock``; simulation time 0 is ``EPOCH_NS``, a
   fixed, whole second, so the periods of the nodes' timers fall on sync ticks and every run
   has the same stamps; small, so stamps that pass through float seconds on the way, as
   python-can's frame timestamps, keep ~1e-11 s: at a wall-clock epoch they lost ~1e-7 s);
2. with ``wait_request`` (``rig.lockstep_request``) and once a ``torque_request`` was seen:
   wait for the ``torque_request`` stamped ``T`` (a request source on ``use_sim_time``
   publishing on every ``/clock``, as ``clutch demo --lockstep``'s driver), so the request of
   the tick is on its way to the controller before the frames that lead to its estimate;
3. send the time frame (``TIME_FRAME_ID``: ``T`` on the bus), then the frames due; the
   bridge stamps each frame with the newest time frame before it, whenever its /clock
   arrives (between sync ticks the rig sends none: one frame of each kind per period);
4. wait for the chain's answer to the tick: the ``clutch_estimate`` stamped ``T`` (the bridge
   read the frames, published ``rig_state`` ``T``, the estimator answered it), the
   ``pressure_command`` stamped ``T`` (the controller with ``controller.trigger`` "estimate"
   runs one step per estimate and stamps the command with the estimate's stamp: the command
   answering tick ``T``) and the bridge's report on ``pump_request`` of the frame it sent for
   that very command (its stamp and torques: on simulated time the bridge answers every
   admitted command with a frame and reports it with the command's stamp). The frame went out
   before the report, so the rig's CAN port has it: the plant follows it from ``T`` on
   (frames received during the wait count as received at ``T``).

Why these answers: the PumpRequest frames carry no stamp, and the bridge's periodic frame may
go out before or after it admitted the command of ``T``, so the rig keys on what is stamped
with the tick: the estimate, the controller's command of it, the bridge's report of that
command's frame. Each answer is then the same whatever the order of arrival, and every tick's
command is computed from that tick's estimate (a controller on its own timer could answer
``T`` with the estimate of an earlier tick, depending on the machine's load).
Each wait is bounded by ``rig.lockstep_timeout`` of wall time; an expired wait is counted
(``lockstep_timeouts``, WARN on /diagnostics, with what was missing) and the run goes on.
Until the chain has answered one sync tick completely (it is still starting), a wait gives up
after ``STARTUP_WAIT`` without counting. ``/clock`` is published again (the same time: no
jump) every ``REPUBLISH`` while waiting, for late subscribers and lost samples.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import can
from clutch_msgs.msg import ClutchEstimate, PressureCommand, TorqueRequest
from rosgraph_msgs.msg import Clock

from clutch_ros.interfaces import CLUTCH_ESTIMATE, PRESSURE_COMMAND, PUMP_REQUEST, TORQUE_REQUEST
from clutch_ros.nodes.qos import subscriber_qos

__all__ = ["EPOCH_NS", "REPUBLISH", "STARTUP_WAIT", "TIME_FRAME_ID", "LockStepSync",
           "time_frame", "time_of_frame"]

#: CAN identifier of the lock-step time frame (as CANopen's TIME object, not in the rig's
#: DBC): the rig sends it before a sync tick's frames, 8 bytes, the tick's ROS time [ns] as
#: little-endian uint64; the bridge's receive thread reads it from the same ordered stream as
#: the frames, so it stamps every frame of the tick with the tick's time however late its
#: node clock (``/clock`` over DDS) is
TIME_FRAME_ID = 0x7F0

EPOCH_NS = 100_000 * 1_000_000_000  # [ns] ROS time of simulation time 0 (1970-01-02)
REPUBLISH = 0.02  # [s] wall: /clock is published again this often while waiting
STARTUP_WAIT = 0.5  # [s] wall: a wait before the chain first answered gives up after this
_POLL = 0.001  # [s] wall: CAN port poll interval while waiting


def time_frame(ns: int) -> can.Message:
    """Return the lock-step time frame of ROS time ``ns`` [ns] (a ``can.Message``)."""
    return can.Message(arbitration_id=TIME_FRAME_ID, is_extended_id=False,
                       data=int(ns).to_bytes(8, "little"))


def time_of_frame(identifier: int, is_extended: bool, data: bytes) -> float | None:
    """ROS time [s] carried by a lock-step time frame; None for any other frame."""
    if identifier != TIME_FRAME_ID or is_extended or len(data) != 8:
        return None
    return int.from_bytes(data, "little") * 1e-9


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class LockStepSync:
    """The rig's side of lock-step (see the module docstring); a ``LockStep`` of the simulator.

    Args:
        node: the rig node (publisher and subscriptions are made on it; its executor runs
            the callbacks while the simulation thread waits)
        dt: the plant step [s]
        every: plant steps per sync tick
        timeout: wall-clock bound of one wait [s]
        poll: receives pending CAN frames; returns the valid PumpRequests among them
        epoch_ns: ROS time of simulation time 0 [ns] (a whole number of ticks)
        send_time: sends the time frame of a tick [ns] before its frames
        wait_request: wait for the tick's torque_request before its frames (once one came)

    """

    def __init__(self, node, dt: float, every: int, timeout: float,
                 poll: Callable[[], int], epoch_ns: int = EPOCH_NS,
                 send_time: Callable[[int], None] | None = None,
                 wait_request: bool = False) -> None:
        self.every = int(every)
        self.timeout = float(timeout)
        self._dt_ns = round(dt * 1e9)
        self.epoch_ns = int(epoch_ns)
        # a stamp within half a step of a tick answers it (stamps that went through float
        # seconds come back a few 1e-11 s off)
        self._slack_ns = self._dt_ns // 2
        self._poll = poll
        self._send_time = send_time  # sends the time frame of a tick [ns] before its frames
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._estimate_ns = self._request_ns = -1
        self._commands: dict[int, tuple[int, float, float]] = {}  # recent ones: stamp -> key
        self._applied: set[tuple[int, float, float]] = set()  # the bridge's reports of them
        self.started = False
        self._last_ok = True  # the current sync tick's waits were all answered
        self.syncs = self.timeouts = 0
        self.wait_time = 0.0  # [s] wall time spent waiting for the chain
        self.wait_max = 0.0  # [s] wall time of the longest wait (started) answered
        self.last_timeout = ""
        self._clock = Clock()
        self._pub = node.create_publisher(Clock, "/clock", 10)
        node.create_subscription(PressureCommand, PRESSURE_COMMAND.name, self._on_command,
                                 subscriber_qos(PRESSURE_COMMAND.name, depth=10))
        node.create_subscription(PressureCommand, PUMP_REQUEST.name, self._on_applied,
                                 subscriber_qos(PUMP_REQUEST.name, depth=10))
        node.create_subscription(ClutchEstimate, CLUTCH_ESTIMATE.name, self._on_estimate,
                                 subscriber_qos(CLUTCH_ESTIMATE.name, depth=10))
        if wait_request:
            node.create_subscription(TorqueRequest, TORQUE_REQUEST.name, self._on_request,
                                     subscriber_qos(TORQUE_REQUEST.name, depth=10))

    def now_ns(self, t: float) -> int:
        """ROS time [ns] of simulation time ``t`` [s] (exact on plant steps)."""
        return self.epoch_ns + round(t / (self._dt_ns * 1e-9)) * self._dt_ns

    def stamp(self, t: float) -> float:
        """ROS time [s] of simulation time ``t`` [s] (the stamp of the rig's frames)."""
        return self.now_ns(t) * 1e-9

    def stop(self) -> None:
        """End any wait at once (thread-safe); later waits return at once."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def _on_command(self, msg) -> None:
        with self._cond:
            ns = _ns(msg.header.stamp)
            self._commands = {k: v for k, v in self._commands.items()
                              if k >= ns - 10 * self._dt_ns * self.every}
            self._commands[ns] = (ns, msg.requested_torque, msg.predicted_torque)
            self._cond.notify_all()

    def _on_applied(self, msg) -> None:
        """Keep the bridge's report of a frame sent for an admitted command (stamp, torques)."""
        with self._cond:
            ns = _ns(msg.header.stamp)
            self._applied = {k for k in self._applied
                             if k[0] >= ns - 10 * self._dt_ns * self.every}
            self._applied.add((ns, msg.requested_torque, msg.predicted_torque))
            self._cond.notify_all()

    def _on_request(self, msg) -> None:
        with self._cond:
            self._request_ns = max(self._request_ns, _ns(msg.header.stamp))
            self._cond.notify_all()

    def _on_estimate(self, msg) -> None:
        with self._cond:
            self._estimate_ns = max(self._estimate_ns, _ns(msg.header.stamp))
            self._cond.notify_all()

    def _publish(self, ns: int) -> None:
        self._clock.clock.sec, self._clock.clock.nanosec = divmod(ns, 1_000_000_000)
        self._pub.publish(self._clock)

    def before_frames(self, t: float) -> None:
        """Publish ``/clock`` = ``t`` (wait for its request) and send the tick's time frame."""
        ns = self.now_ns(t)
        self._publish(ns)
        self._last_ok = True
        if self._request_ns >= 0:  # (only with wait_request, once requests flow)
            self._last_ok = self._wait(ns, lambda: "" if self._request_ns >= ns - self._slack_ns
                                       else "no torque_request stamped at the tick")
        if self._send_time is not None:
            self._send_time(ns)

    def _command_of(self, ns: int) -> tuple[int, float, float] | None:
        """Return the newest command stamped at the tick ``ns`` (within half a step), or None."""
        keys = [k for k in self._commands if abs(k - ns) <= self._slack_ns]
        return self._commands[max(keys)] if keys else None

    def after_frames(self, t: float) -> None:
        """Wait for the estimate of the frames just sent, its command and that command's frame."""
        ns = self.now_ns(t)

        def answered() -> str:
            self._poll()  # (frames received while waiting count as received at the tick)
            if self._estimate_ns < ns - self._slack_ns:
                return "no clutch_estimate stamped at the tick"
            key = self._command_of(ns)
            if key is None:
                return "no pressure_command stamped at the tick (controller.trigger estimate?)"
            if key not in self._applied:
                return "no pump_request report of the tick's command from the bridge"
            self._poll()  # its frame was sent before the report: take it in now
            return ""
        self._last_ok = self._wait(ns, answered) and self._last_ok
        if not self._stop.is_set():
            self.syncs += 1
            self.started = self.started or self._last_ok

    def _wait(self, ns: int, missing: Callable[[], str]) -> bool:
        """Wait until ``missing()`` is empty (True) or the bound expires (False, counted)."""
        start = time.monotonic()
        bound = start + (self.timeout if self.started else STARTUP_WAIT)
        next_publish = start + REPUBLISH
        why = missing()
        while why and not self._stop.is_set():
            now = time.monotonic()
            if now >= bound:
                if self.started:
                    self.timeouts += 1
                    self.last_timeout = (f"{why} (T = {ns * 1e-9:.3f} s) within "
                                         f"{self.timeout:g} s")
                break
            if now >= next_publish:
                self._publish(ns)
                next_publish = now + REPUBLISH
            with self._cond:
                self._cond.wait(min(_POLL, bound - now))
            why = missing()
        waited = time.monotonic() - start
        self.wait_time += waited
        if self.started and not why:
            self.wait_max = max(self.wait_max, waited)
        return not why

    def values(self) -> dict:
        """Figures for /diagnostics."""
        return {"lockstep_syncs": self.syncs, "lockstep_timeouts": self.timeouts,
                "lockstep_wait_s": self.wait_time, "lockstep_wait_max_s": self.wait_max,
                "lockstep_last_timeout": self.last_timeout,
                "lockstep_started": self.started}
