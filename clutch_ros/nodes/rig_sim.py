"""The ``rig_sim`` node: the embedded simulated rig, speaking the rig DBC on a CAN bus.

A thin adapter around :class:`clutch_ros.rig.RigSimulator`: the truth plant
(``rig.params_file``, default the ``rig_truth`` preset: a pack with the ``coulomb`` spline law
and parameters deliberately different from the estimator's), pump dynamics with the pressure
kick, a thermal model, sensor noise and FlexiForce voltages, stepped at ``rig.dt`` in real
time in a background thread. It sends the rig frames at their DBC cycle times and follows
the pump pressure requests it receives (counter and CRC checked; 0 bar when they stop).

Modes: ``rig.scenario`` empty is the operator mode: the motor holds ``rig.slip_speed``
(settable at run time with ``ros2 param set``, as a test engineer sets the rig motor) and the
pump follows the bus. Otherwise a scripted run of the thesis (Tables 3-4):
``table3:SEQ:RPM`` (DBP), ``table4:SEQ`` (PBD), or ``closed_loop[:RPM,...[:SEGMENT_S]]``.
Frames are stamped with the wall clock (like a real adapter's receive time).

Lock-step (``rig.lockstep``, read-only): the rig is the ROS graph's clock instead of keeping
real time. It publishes ``/clock`` every ``rig.lockstep_period`` and waits, at most
``rig.lockstep_timeout`` of wall time, for the chain (every node with ``use_sim_time``) to
answer each such tick before it steps on (:mod:`clutch_ros.nodes.lockstep`); frames are then
stamped with that clock. A run is then the same however loaded the machine is; /diagnostics
counts the waits that expired (``lockstep_timeouts``, WARN).

The rig's CAN database is ``bridge.dbc_file``, the bridge's parameter (empty: the package's
``params/rig.dbc``). Only ``rig.slip_speed`` changes at run time (operator mode); the bus, the
DBC, the plant, the scenario, the step and the seed are read-only (fixed when the simulation
starts). Its /diagnostics
``hardware_id`` is ``simulated rig (interface:channel)``; it reports ``overruns`` and
``lost_time_s`` [s], the real time the loop dropped when it fell more than 0.1 s behind (a
machine short of CPU: the simulated world then runs slower than real time), and is WARN in a
report whose period dropped any.
"""

from __future__ import annotations

import math
import threading
import time

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node

from clutch_ros.canbus import BusConfig, ReconnectingBus
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.nodes.diagnostics import Diagnostics
from clutch_ros.nodes.lockstep import LockStepSync, time_frame
from clutch_ros.nodes.parameters import DBC_FILE_PARAM, ParamSpec, declare_params
from clutch_ros.nodes.runner import run_node
from clutch_ros.rig import RigPlant, RigSimulator
from clutch_ros.rig.can_io import RigCanPort
from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.scenario import Scenario, ScenarioPoint, scenario_from_spec

NAME = "rig_sim"
_AT_START = "read-only: the bus is opened at start"
PARAMS = [
    ParamSpec("can.interface", "udp_multicast",
              f"python-can interface of the simulated rig; {_AT_START}", read_only=True),
    ParamSpec("can.channel", "239.74.163.2",
              f"interface channel: a name (multicast group, can0 ...) or a number (Vector: 0); "
              f"{_AT_START}", read_only=True, dynamic_typing=True),
    ParamSpec("can.port", 43113, f"UDP port (udp_multicast only); {_AT_START}", "", 1, 65535,
              read_only=True),
    DBC_FILE_PARAM,
    ParamSpec("rig.params_file", "rig_truth",
              "truth-plant parameter file or preset name; read-only: the plant is built at start",
              read_only=True),
    ParamSpec("rig.scenario", "", "empty: operator mode (rig.slip_speed, pump from the bus); "
              "or table3:SEQ:RPM, table4:SEQ, closed_loop[:RPM,...[:SEGMENT_S]]; read-only: the "
              "run is scheduled at start", read_only=True),
    ParamSpec("rig.repeat", False, "restart a scripted scenario at its end; read-only: part of "
              "the schedule made at start", read_only=True),
    ParamSpec("rig.slip_speed", 0.0, "operator mode: slip speed held by the rig motor",
              "rad/s", -100.0, 100.0),
    ParamSpec("rig.dt", 0.001, "simulation step; read-only: the run's time base is fixed at "
              "start", "s", 1e-4, 0.01, read_only=True),
    ParamSpec("rig.lockstep", False, "publish /clock and wait for the chain (use_sim_time "
              "nodes) every rig.lockstep_period instead of keeping real time; read-only: the "
              "run's time base is fixed at start", read_only=True),
    ParamSpec("rig.lockstep_period", 0.01, "lock-step: simulation time between /clock ticks, "
              "a whole number of rig.dt (the controller's and the bridge's period); read-only: "
              "fixed at start", "s", 1e-4, 1.0, read_only=True),
    ParamSpec("rig.lockstep_timeout", 2.0, "lock-step: wall time the rig waits for the chain's "
              "answer to a tick before it goes on (counted); read-only: fixed at start", "s",
              0.01, 60.0, read_only=True),
    ParamSpec("rig.lockstep_request", False, "lock-step: once a torque_request came, also wait "
              "for the one stamped at each tick before sending the tick's frames (a request "
              "source on use_sim_time publishing on every /clock, as clutch demo's): the "
              "controller has the tick's request before its estimate; read-only: fixed at start",
              read_only=True),
    ParamSpec("rig.seed", 0, "seed of the sensor variation and noise; read-only: drawn at start",
              "", 0, 2**31 - 1, read_only=True),
]


#: This node's parameters fixed at start (the rt.* ones are declared read-only by run_node).
_READ_ONLY = frozenset(spec.name for spec in PARAMS if spec.read_only)


class _OperatorScenario(Scenario):
    """Closed loop with the slip speed set by the operator (the node parameter).

    A :class:`Scenario` without its constructor: the attributes below are fixed.
    """

    closed_loop = True
    name = "operator"
    duration = math.inf
    initial_lamella_temperature = 35.0
    repeat = False

    def __init__(self, slip_speed: float) -> None:  # (Scenario.__init__ not called)
        self.slip_speed = slip_speed

    def at(self, t: float) -> ScenarioPoint:
        """Return the operator's command at ``t`` [s]: bus pressure, held slip speed."""
        return ScenarioPoint(math.nan, self.slip_speed, math.nan)


class RigSimNode(Node):
    """The simulated rig (see module docstring)."""

    def __init__(self):
        super().__init__(NAME)

        cfg = self._cfg = declare_params(self, PARAMS)
        plant = RigPlant.from_file(cfg["rig.params_file"], seed=cfg["rig.seed"])
        if cfg["rig.scenario"]:
            self._scenario = scenario_from_spec(cfg["rig.scenario"], repeat=cfg["rig.repeat"])
        else:
            self._scenario = _OperatorScenario(cfg["rig.slip_speed"])
        database = RigDatabase(cfg["bridge.dbc_file"] or None)  # (before the bus is opened)
        self._bus = ReconnectingBus(BusConfig.from_params(cfg))
        self._port = RigCanPort(self._bus, database)
        self._lockstep = None
        stamp_clock = time.time
        if cfg["rig.lockstep"]:
            every = round(cfg["rig.lockstep_period"] / cfg["rig.dt"])
            if every < 1 or abs(every * cfg["rig.dt"] - cfg["rig.lockstep_period"]) > 1e-9:
                raise RigConfigError(f"rig.lockstep_period {cfg['rig.lockstep_period']} s is "
                                     f"not a whole number of rig.dt {cfg['rig.dt']} s")
            self._lockstep = LockStepSync(self, cfg["rig.dt"], every,
                                          cfg["rig.lockstep_timeout"],
                                          lambda: self._port.poll(self._sim.time),
                                          send_time=lambda ns: self._bus.send(
                                              time_frame(ns), timeout=0.05),
                                          wait_request=cfg["rig.lockstep_request"])
            stamp_clock = self._lockstep_stamp
        self._sim = RigSimulator(plant, self._scenario, self._port, dt=cfg["rig.dt"],
                                 stamp_clock=stamp_clock, lockstep=self._lockstep)
        self._stats = None
        self._lost_reported = 0.0  # [s] sim.lost_time at the last /diagnostics report
        self._timeouts_reported = 0  # lock-step timeouts at the last WARN
        self._thread = threading.Thread(target=self._run, name="rig_sim", daemon=True)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag = Diagnostics(self, self._diagnose, hardware_id=(
            f"simulated rig ({cfg['can.interface']}:{cfg['can.channel']})"))
        self._thread.start()
        self.get_logger().info(f"simulated rig running scenario '{self._scenario.name}' "
                               f"{'in lock-step ' if self._lockstep else ''}on "
                               f"{cfg['can.interface']}:{cfg['can.channel']} with DBC "
                               f"{database.path}")

    def _lockstep_stamp(self) -> float:
        assert self._lockstep is not None  # (only passed in lock-step)
        return self._lockstep.stamp(self._sim.time)

    def _run(self) -> None:
        duration = math.inf if (self._scenario.repeat or self._scenario.duration == math.inf) \
            else self._scenario.duration
        try:
            self._stats = self._sim.run(duration, realtime=self._lockstep is None)
            if not self._stats.stopped:  # (a stop comes from close(), after rclpy shut down)
                self.get_logger().info(f"scenario done: {self._stats}")
        except Exception as err:  # noqa: BLE001 - reported, the node keeps its diagnostics
            self.get_logger().error(f"simulation stopped: {err}")

    def _on_set_parameters(self, params) -> SetParametersResult:
        for p in params:  # all or nothing: check every parameter before applying any
            if p.name == "rig.slip_speed" and not isinstance(self._scenario, _OperatorScenario):
                return SetParametersResult(successful=False, reason="rig.slip_speed is only "
                                           "settable in operator mode")
            if p.name in _READ_ONLY:  # (ROS refuses read-only sets itself; so does this)
                return SetParametersResult(successful=False,
                                           reason=f"{p.name} cannot change at run time")
        for p in params:
            if p.name == "rig.slip_speed" and isinstance(self._scenario, _OperatorScenario):
                self._scenario.slip_speed = float(p.value)  # (checked above)
        return SetParametersResult(successful=True)

    def _diagnose(self):
        sim, port = self._sim, self._port
        values = {"sim_time_s": sim.time, "steps": sim.steps, "frames_sent": port.sent,
                  "send_errors": port.send_errors, "frames_received": port.received,
                  "pump_requests": port.received - port.other_frames,
                  "invalid_pump_requests": port.monitor.invalid,
                  "requested_pressure_pa": port.requested_pressure(sim.time),
                  "own_echoes_dropped": self._bus.own_echoes,
                  "overruns": sim.overruns, "lost_time_s": sim.lost_time}
        lockstep = self._lockstep
        if lockstep is not None:
            values.update(lockstep.values())
        if sim.signals is not None:
            values.update(actuating_pressure_pa=sim.signals.actuating_pressure,
                          true_torque_nm=sim.signals.true_torque,
                          lamella_temperature_c=sim.signals.lamella_temperature)
        if not self._thread.is_alive():
            if self._stats is not None:
                return "OK", f"scenario '{self._scenario.name}' done", values
            return "WARN", "simulation not running", values
        if lockstep is not None and lockstep.timeouts > self._timeouts_reported:
            self._timeouts_reported = lockstep.timeouts
            return "WARN", (f"lock-step: {lockstep.timeouts} waits for the chain expired; "
                            f"last: {lockstep.last_timeout}"), values
        lost, self._lost_reported = sim.lost_time - self._lost_reported, sim.lost_time
        if lost > 0.0:  # the plant did not run for that long: a slowed world, not a rig's
            return "WARN", (f"simulation fell behind real time and dropped {lost:.3f} s since "
                            "the last report (the machine is short of CPU)"), values
        return "OK", f"running '{self._scenario.name}'", values

    def close(self) -> None:
        """Stop the simulation thread and close the bus."""
        self._sim.stop()
        if self._lockstep is not None:
            self._lockstep.stop()
        self._thread.join(timeout=2.0)
        self._bus.shutdown()


def main(args=None) -> int:
    """Console entry point: ``ros2 run clutch_ros rig_sim``; bad settings: one line, exit 2."""
    return run_node(NAME, __doc__, PARAMS, RigSimNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
