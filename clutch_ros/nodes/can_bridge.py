"""The ``can_bridge`` node: rig CAN frames <-> typed topics, and pump pressure requests.

A managed (lifecycle) node, as ros2_socketcan's bridge: ``configure`` loads the DBC and the
signal map (``map.*``, :mod:`clutch_ros.canbus.signal_map`: which message and signal feed each
RigState field and the pump request; a missing one fails the transition with a line naming
it) and opens the bus; ``activate`` starts publishing ``rig_state`` and sending PumpRequests;
``deactivate`` sends 0 bar at once and stops both; ``cleanup`` and ``shutdown`` close the bus.
``autostart`` (default true) configures and activates at start, so ``ros2 run`` works as a
plain node; a start-up failure then prints one line and exits 2. Services:
``~/change_state``, ``~/get_state`` (lifecycle_msgs).

Receive: frames are read on a receive thread from configure on (counted and decoded into
the live sample, diagnosed) and published only while active
(:mod:`clutch_ros.nodes.can_bridge_receive`). Our own frames looped back by the interface
are removed by the bus.

Send: ``pressure_command`` goes through :class:`clutch_ros.canbus.PumpCommandGate` (clamp to
``pump.max_pressure``, rate limit, 0 bar after ``pump.watchdog_timeout`` without an admitted
command; stale, future, out-of-order, unstamped commands, commands from a node other than
``pump.command_source`` and commands while inactive are refused and counted). The
PumpRequest (rolling counter + CRC-8) goes out every ``pump.period``, carrying the newest
command taken at that cycle (a command waits at most one period); what was applied and why
is published on ``pump_request`` (:mod:`clutch_ros.nodes.can_bridge_send`). The cycle
(``pump.period``: commands, the frame, the watchdog) and the ``bridge.rate`` flush run on a
thread of their own from configure to cleanup (:mod:`clutch_ros.nodes.cycle`: an executor
wake-up per call or command cost more CPU than the work). With ``use_sim_time`` they are ROS
timers while active, commands are executor callbacks, and each admitted command is answered
by a frame at once (lock-step).
SIGINT/SIGTERM while active send a last 0 bar PumpRequest; a killed bridge sends nothing, and
the pump ECU goes to 0 bar on its own request timeout (100 ms, ``params/rig.dbc``).

Parameters: the pump limits, ``pump.period``, ``bridge.rate``, ``bridge.publish_on`` and
``pump.command_source`` apply live, validated (an out-of-range or inconsistent value is
refused with the reason; a new ``pump.max_pressure`` holds from the next frame on); the bus,
DBC, signal map and log input are read-only (:mod:`clutch_ros.nodes.can_bridge_params`).
``pump.rate_limit`` was renamed ``pump.rise_rate_limit`` (as ``controller.rise_rate_limit``);
the old name is still accepted, at start and live, with a deprecation warning.

QoS (REP 2003): each publisher offers its topic's profile of :data:`clutch_ros.interfaces.TOPICS`
(all reliable, so default and sensor-data subscribers both receive: ``rig_state`` keep last
50, ``pump_request`` 50, ``can_frames`` 1000, ``/diagnostics`` 10); ``pressure_command`` is read
with sensor-data QoS (best effort, keep last 5): only the latest command counts.

Diagnostics ``hardware_id``: ``interface:channel`` of the bus (``socketcan:can0``),
``simulated rig (udp_multicast:GROUP)`` on python-can's software buses (udp_multicast,
virtual: the simulated rig's), ``log:PATH`` for ``input.log_file`` (or the
``diagnostics.hardware_id`` parameter when set).
"""

from __future__ import annotations

import threading
import time

from clutch_msgs.msg import CanFrame, PressureCommand, RigState
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from clutch_ros.canbus import (
    BusConfig,
    LogSource,
    PumpCommandGate,
    ReconnectingBus,
    RigDatabase,
    RigStateAssembler,
)
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.canbus.intake import CompiledIntake, unavailable_reason
from clutch_ros.canbus.intake import warm_up as load_intake
from clutch_ros.canbus.signal_map import SignalMap
from clutch_ros.errors import ClutchError
from clutch_ros.interfaces import CAN_FRAMES, PUMP_REQUEST, RIG_STATE
from clutch_ros.nodes.can_bridge_params import (
    GATE_PARAMS,
    LIVE,
    PARAMS,
    RENAMED,
    check_change,
    gate_config,
    signal_specs,
)
from clutch_ros.nodes.can_bridge_receive import FLUSH_PERIOD, ReceiveSide
from clutch_ros.nodes.can_bridge_send import PumpSender
from clutch_ros.nodes.can_bridge_state import BridgeState
from clutch_ros.nodes.can_diagnostics import hardware_id, node_status
from clutch_ros.nodes.command_sources import CommandSources
from clutch_ros.nodes.convert import RigStateEncoder
from clutch_ros.nodes.cycle import Cycle
from clutch_ros.nodes.diagnostics import Diagnostics, LogThrottle
from clutch_ros.nodes.parameters import HARDWARE_ID_PARAM
from clutch_ros.nodes.qos import publisher_qos
from clutch_ros.nodes.renamed_params import declare_with_renames
from clutch_ros.nodes.runner import run_interruptibly, run_node

NAME = "can_bridge"
IDLE_TIMEOUT = 1.0  # [s] no new rig frame for this long: one warning
OK, FAIL = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE


class CanBridgeNode(ReceiveSide, LifecycleNode):
    """Rig CAN <-> ROS bridge, a lifecycle node (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)
        cfg = self._cfg = declare_with_renames(self, PARAMS, RENAMED)
        reason = check_change(cfg, None)  # the start values, as a later change would be
        if reason is not None:
            raise ClutchError(reason)
        self._lock, self._failure = threading.Lock(), None
        self._cycle_warn, self._cycle = LogThrottle(5.0), None  # (Cycle while active)
        self._sim_time = False  # use_sim_time, read at configure
        self._time_floor = 0.0  # [s] sim time: the newest command stamp (see _node_time)
        self._rig_pub = self._raw_pub = self._rx = None
        self._rig_encode = RigStateEncoder().encode  # rig_state written as CDR bytes
        self._rx_stop = threading.Event()
        self._pump_timer = self._flush_timer = None
        #: the bridge's components, counters and lifecycle state, read by its diagnostics
        self.state = BridgeState(CommandSources(self, cfg["pump.command_source"]))
        self._pump = PumpSender(self, self.state, self._saw_stamp)  # the send side
        self._diag = Diagnostics(self, self._diagnose, hardware_id=(
            cfg[HARDWARE_ID_PARAM.name] or hardware_id(cfg)))
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._apply_params)
        if cfg["autostart"]:
            try:
                for step in (self.trigger_configure, self.trigger_activate):
                    if step() != OK:
                        raise self._failure or ClutchError(f"{step.__name__} failed")
            except BaseException:
                # the runner never gets this node: stop what configure started (receive and
                # cycle threads, bus) and leave the graph, as the runner does with a node
                # it built (a stop signal during configure ends here too)
                self.close()
                self.destroy_node()
                raise

    def _load_intake(self) -> bool:
        """Load the compiled intake if configure uses it; return whether it does.

        It does with ``bridge.compiled``, on the wall clock and without ``bridge.publish_raw``
        (configure asks on a bus only). numba's first load takes more than 5 s beside busy
        processes and an import cannot be interrupted, so it runs in a thread that a stop
        signal gives up waiting for. Loaded once per process, after the bus is open, so its
        socket queues the rig's frames meanwhile and the first samples have every frame group
        (tests/nodes/test_can_bridge_lag.py).

        A stop meanwhile raises KeyboardInterrupt, the stop the user asked for: it passes
        rclpy's lifecycle, which turns any ``Exception`` of a transition into an ERROR log
        and a failed transition; the autostart then closes the bridge and the runner exits 0.
        """
        if not self._cfg["bridge.compiled"] or self._cfg["bridge.publish_raw"] \
                or self._sim_time:  # (configure has read use_sim_time)
            return False
        if not run_interruptibly(load_intake, lambda: not self.context.ok()):
            raise KeyboardInterrupt("stopped while the compiled intake was loading")
        return True

    # -- lifecycle ------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        """Load the DBC and signal map, open the bus (or check the log); create the topics."""
        cfg, st = self._cfg, self.state
        st.clear()  # counters from zero
        st.last_new = time.monotonic()
        try:
            db = RigDatabase(cfg["bridge.dbc_file"] or None, strict_units=False)
            st.assembler = RigStateAssembler(db, signal_map=SignalMap(signal_specs(cfg)),
                                             socketcan_error_frames=cfg["can.interface"]
                                             == "socketcan")
            # use_sim_time (a lock-step rig's /clock): the node clock is the time base of
            # the frames, the gate's watchdog and rate limit, and the pacer, not the PC's
            self._sim_time = self._pump.sim_time = bool(self.get_parameter("use_sim_time").value)
            st.gate = PumpCommandGate(self._node_time if self._sim_time else time.monotonic,
                                      gate_config(cfg), st.assembler.map.pump,
                                      stamp_clock=self._node_time)
            st.pacer = PublishPacer(cfg["bridge.rate"], self._trigger(
                cfg["bridge.publish_on"]), frozenset(st.assembler.map.writes))
            if cfg["input.log_file"]:
                st.source = LogSource(cfg["input.log_file"], realtime=cfg["input.realtime"])
                st.source.check()  # a bad file fails the transition with a clear message
            else:
                config = BusConfig.from_params(cfg)
                st.bus = ReconnectingBus(config, on_event=self._on_link_event)
                if self._load_intake():
                    st.intake = CompiledIntake(st.assembler, st.pacer,
                                               (st.gate.codec.spec.key,))
                    if not st.intake.ready:
                        self.get_logger().warning(f"bridge.compiled: {unavailable_reason()}; "
                                                  "the rig frames are decoded in Python")
                        st.intake = None
                self._rx_stop.clear()
                self._rx = threading.Thread(target=self._receive, args=(st.bus,),
                                            name="can_rx", daemon=True)
                self._rx.start()
                self.get_logger().info(f"CAN {config.describe()} open; decoding with {db.path}")
                st.sources.topic = self._pump.subscribe(polled=not self._sim_time)
                if not self._sim_time:  # (frames and rig_state only while active)
                    pacer = st.pacer
                    self._cycle = Cycle("can_cycle", {
                        "pump": (cfg["pump.period"], self._pump.cycle),
                        "flush": (self._flush_period(),
                                  lambda: self._publish_latest(pacer.flush))},
                        self._on_cycle_error).start()
        except (ClutchError, ValueError) as err:
            self._failure = err
            self.get_logger().error(f"configure failed: {err}")
            self._close_bus()
            st.clear()
            return FAIL
        self._rig_pub = self.create_lifecycle_publisher(
            RigState, RIG_STATE.name, publisher_qos(RIG_STATE.name))
        self._pump.publisher = self.create_lifecycle_publisher(
            PressureCommand, PUMP_REQUEST.name, publisher_qos(PUMP_REQUEST.name))
        self._raw_pub = (self.create_lifecycle_publisher(
            CanFrame, CAN_FRAMES.name, publisher_qos(CAN_FRAMES.name))
                         if cfg["bridge.publish_raw"] else None)
        st.lifecycle = "inactive"
        return super().on_configure(state)

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Start publishing rig_state and sending PumpRequests."""
        result = super().on_activate(state)  # enables the lifecycle publishers
        st = self.state
        if st.source is not None:
            st.stop.clear()
            st.log_thread = threading.Thread(target=self._replay, name="can_log", daemon=True)
            st.log_thread.start()
        elif self._sim_time:  # on the node's (simulated) clock: ROS timers, until deactivate
            # (on the wall clock the cycle runs from configure: see can_bridge_send)
            pacer = st.pacer
            assert st.gate is not None and pacer is not None  # configured
            self._pump_timer = self.create_timer(self._cfg["pump.period"], self._pump.tick)
            self._flush_timer = self.create_timer(
                self._flush_period(), lambda: self._publish_latest(pacer.flush))
        st.active, st.lifecycle = True, "active"
        return result

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Send 0 bar at once, then stop publishing and sending."""
        self._halt("deactivate")
        self.state.lifecycle = "inactive"
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        """Close the bus, remove the topics and clear the state."""
        self._close_bus()
        for pub in (self._rig_pub, self._pump.publisher, self._raw_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
        self._pump.unsubscribe()
        self._rig_pub = self._pump.publisher = self._raw_pub = None
        self.state.clear()
        self.state.lifecycle = "unconfigured"
        return super().on_cleanup(state)

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        """From any state: 0 bar when active, close the bus."""
        self.close()
        self.state.lifecycle = "finalized"
        return super().on_shutdown(state)

    def _halt(self, why: str) -> None:
        """Stop sending and publishing; a last 0 bar PumpRequest when the bus is open."""
        st = self.state
        # under the lock the receive thread publishes with: a publish that passed its
        # "active" check has ended when this returns, so none follows the transition
        with self._lock:
            was_active, st.active = st.active, False
        # the cycle (configure..cleanup) sends no frame once inactive: PumpSender.tick checks
        # under the lock zero() sends with, so the 0 bar frame below is the last one
        for timer in (self._pump_timer, self._flush_timer):
            if timer is not None:
                timer.cancel()
                self.destroy_timer(timer)
        self._pump_timer = self._flush_timer = None
        st.stop.set()
        if st.log_thread is not None:
            st.log_thread.join(timeout=2.0)
        if was_active and st.bus is not None and st.gate is not None:  # (gate: with the bus)
            self._pump.zero(why)

    def _close_bus(self) -> None:
        st = self.state
        if self._cycle is not None:  # ended: no job after it, before the bus closes
            self._cycle.stop()
            self._cycle = None
        self._rx_stop.set()
        if self._rx is not None:
            self._rx.join(timeout=2.0)
        if st.bus is not None:
            st.bus.shutdown()
        self._rx = st.bus = st.source = None

    def close(self) -> None:
        """Send a last 0 bar request when active, stop the threads, close the bus, unsubscribe."""
        self._halt("shutdown")
        self._close_bus()
        self._pump.unsubscribe()  # (after the cycle that takes from it stopped)

    def _node_time(self) -> float:
        """Return the node clock [s] (ROS time: /clock with use_sim_time).

        With use_sim_time, never earlier than the newest admitted command's stamp (a command
        stamped T proves that /clock reached T) nor the newest lock-step time frame on the bus
        (sent before a tick's frames, which must be stamped T even when this node's /clock
        is late: :mod:`clutch_ros.nodes.lockstep`).
        """
        if not self._sim_time:  # the ROS clock is the system clock: time.time() without
            return time.time()  # rclpy's Time object (~10 us; ~200 calls/s on the cycle)
        return max(self.get_clock().now().nanoseconds * 1e-9, self._time_floor)

    # -- parameters -----------------------------------------------------------------------
    def _check_params(self, params) -> SetParametersResult:
        values = dict(self._cfg)
        values.update({p.name: p.value for p in params if p.name in self._cfg})
        gate = self.state.gate
        reason = check_change(values, gate.codec.max_pressure if gate else None)
        if reason is None and self.state.assembler is not None and any(
                p.name == "bridge.publish_on" for p in params):
            try:
                self._trigger(values["bridge.publish_on"])
            except ClutchError as err:
                reason = str(err)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _apply_params(self, params) -> None:
        """Apply accepted live values at once (before the next frame)."""
        names = {p.name for p in params if p.name in LIVE}
        self._cfg.update({p.name: p.value for p in params if p.name in self._cfg})
        cfg, st = self._cfg, self.state
        if names & set(GATE_PARAMS):
            self._pump.reconfigure(gate_config(cfg))
        if "pump.command_source" in names:
            st.sources.wanted = cfg["pump.command_source"].strip()
        if "pump.period" in names:
            self._set_period("pump", self._pump_timer, cfg["pump.period"])
        if names & {"bridge.rate", "bridge.publish_on"} and st.pacer is not None:
            with self._lock:
                st.pacer.rate = cfg["bridge.rate"]
                st.pacer.trigger = self._trigger(cfg["bridge.publish_on"])
            self._set_period("flush", self._flush_timer, self._flush_period())
        if names:
            self.get_logger().info("applied " + ", ".join(f"{n}={cfg[n]!r}"
                                                          for n in sorted(names)))

    def _set_period(self, job: str, timer, period: float) -> None:
        """Apply a new ``period`` [s] to a cycle job (or its timer, on simulated time)."""
        if self._cycle is not None:
            self._cycle.set_period(job, period)
        elif timer is not None:
            timer.timer_period_ns = int(period * 1e9)

    def _trigger(self, name: str) -> int | None:
        """Frame key of ``bridge.publish_on`` (a DBC message or a signal map key)."""
        if not name:
            return None
        assembler = self.state.assembler
        assert assembler is not None  # configure made it (callers check)
        message = assembler.map.messages.get(name, name)
        return assembler.db.frame(message).key

    def _flush_period(self) -> float:
        period = 1.0 / self._cfg["bridge.rate"]  # with publish_on: only flushes held frames
        pacer = self.state.pacer
        assert pacer is not None  # configured
        return period if pacer.trigger is None else max(period, FLUSH_PERIOD)

    # -- send (can_bridge_send) ----------------------------------------------------------
    def _saw_stamp(self, stamp: float) -> None:
        if self._sim_time and stamp > self._time_floor:  # (see _node_time)
            self._time_floor = stamp

    def _on_cycle_error(self, job: str, err: BaseException) -> None:
        if self._cycle_warn.ready():
            self.get_logger().error(f"{job} cycle: {type(err).__name__}: {err}")

    # -- health ---------------------------------------------------------------------------
    def _diagnose(self):
        return node_status(self.state, self.get_logger(), IDLE_TIMEOUT)


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros can_bridge``; bad settings: one line, exit 2."""
    return run_node(NAME, __doc__, PARAMS, CanBridgeNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
