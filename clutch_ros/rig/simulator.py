"""RigSimulator: the truth plant, a scenario and the CAN port, stepped at 1 kHz.

One tick of length ``dt`` at simulation time ``t`` [s]:

1. receive pending frames (``port.poll(t)``: PumpRequests checked and recorded at ``t``);
2. choose the pressure request: the scenario's own schedule for a scripted run (evaluated at
   ``t + dt``: a scenario's command is held over the step ending at its time), or, in
   closed loop (``scenario.closed_loop``), the latest valid request from the bus — 0 Pa when
   none arrived within the timeout or the last one failed its E2E check (the pump ECU's
   behaviour); without a port, a closed-loop run asks ``pressure_source(t, last_signals)``;
3. step the plant to ``t + dt`` with that request and the scenario's slip-speed command and
   torque request at ``t + dt``;
4. send the frames due at ``t + dt`` (DBC cycle times) and call ``on_step(signals)``.

:meth:`RigSimulator.run` repeats ticks for a duration, either as fast as possible
(``realtime=False``: deterministic, for tests and golden data) or paced by the ``clock``
passed in (``realtime=True``). A real-time loop that falls more than ``max_lag`` behind
(a stalled machine) drops the lost time instead of bursting and counts an overrun. ``stop()``
ends a run from another thread (the ROS node runs the loop in a thread). Runs continue where
the previous one ended.

Lock-step (``lockstep``, a :class:`LockStep`): the run is paced by the chain that answers the
rig instead of by a clock. Every ``lockstep.every`` ticks (a sync tick) step 4 becomes: call
``lockstep.before_frames(t)`` (publish the time), send the frames due, call
``lockstep.after_frames(t)`` (wait for the chain's answer to them, the pump request of the
next steps); between
sync ticks no frames are sent (a frame due then goes out at the next sync tick, once: the
scheduler does not burst). Run it with ``realtime=False``: the waits are the pacing.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, Protocol

import numpy as np

from clutch_ros.rig.errors import RigConfigError, check_positive
from clutch_ros.rig.plant import RigPlant, RigSignals
from clutch_ros.rig.scenario import Scenario

__all__ = ["CanPort", "LockStep", "RigSimulator", "RunStats", "run_offline"]


class CanPort(Protocol):
    """What the simulator needs of a CAN port (:class:`clutch_ros.rig.can_io.RigCanPort`).

    The simulator itself does not depend on python-can: a run without a bus (``port=None``,
    golden data, tests of the model) works where python-can is not installed.
    """

    sent: int  # frames sent so far

    def poll(self, now: float) -> int:
        """Receive pending frames at ``now`` [s]; return the valid pump requests among them."""

    def requested_pressure(self, now: float) -> float:
        """Return the pressure [Pa] the pump follows at ``now`` [s]."""

    def send_due(self, now: float, signals: Any, timestamp: float | None = None) -> int:
        """Send the frames due at ``now`` [s] carrying ``signals``; return how many."""


class LockStep(Protocol):
    """What the simulator needs of a lock-step partner (:mod:`clutch_ros.nodes.lockstep`)."""

    every: int  # ticks per sync tick (>= 1)

    def before_frames(self, t: float) -> None:
        """At sync tick ``t`` [s], before its frames are sent (publish the time)."""

    def after_frames(self, t: float) -> None:
        """At sync tick ``t`` [s], after its frames were sent (wait for the chain's answer)."""


@dataclass
class RunStats:
    """What one :meth:`RigSimulator.run` did.

    Attributes:
        steps: ticks executed
        sim_time: simulation time at the end [s]
        wall_time: clock time the run took [s] (0 for ``realtime=False`` without a clock)
        overruns: times the real-time loop fell more than ``max_lag`` behind and skipped
        frames_sent: frames sent on the bus during the run
        stopped: True when ``stop()`` ended the run early

    """

    steps: int = 0
    sim_time: float = 0.0
    wall_time: float = 0.0
    overruns: int = 0
    frames_sent: int = 0
    stopped: bool = False


class RigSimulator:
    """Run a :class:`~clutch_ros.rig.plant.RigPlant` through a scenario, on a CAN port.

    Args:
        plant: the truth plant (reset by the caller; the scenario's start temperature is
            applied here when ``reset_plant`` is True)
        scenario: scripted or closed-loop schedule (:mod:`clutch_ros.rig.scenario`)
        port: CAN port (None: no bus; closed loop then needs ``pressure_source``)
        dt: tick length [s] (default 1e-3, 1 kHz)
        pressure_source: ``f(t [s], last RigSignals or None) -> Pa`` for closed loop
            without a port
        on_step: called with each tick's RigSignals (e.g. the ROS node's publisher hook)
        stamp_clock: returns the timestamp [s] written into sent frames (default: the
            simulation time); a ROS node passes its wall clock
        reset_plant: reset the plant to the scenario's start temperature now
        lockstep: pace the run by a chain that answers (see the module docstring); None:
            every tick sends its due frames at once

    """

    def __init__(self, plant: RigPlant, scenario: Scenario, port: CanPort | None = None,
                 dt: float = 1e-3,
                 pressure_source: Callable[[float, RigSignals | None], float] | None = None,
                 on_step: Callable[[RigSignals], None] | None = None,
                 stamp_clock: Callable[[], float] | None = None,
                 reset_plant: bool = True, lockstep: LockStep | None = None) -> None:
        self.plant = plant
        self.scenario = scenario
        self.port = port
        self.dt = check_positive("simulator dt", dt)
        self.pressure_source = pressure_source
        self.on_step = on_step
        self.stamp_clock = stamp_clock
        self.lockstep = lockstep
        if lockstep is not None and (isinstance(lockstep.every, bool)
                                     or not isinstance(lockstep.every, int)
                                     or lockstep.every < 1):
            raise RigConfigError(f"lock-step period must be >= 1 tick, got {lockstep.every!r}")
        if scenario.closed_loop and port is None and pressure_source is None:
            raise RigConfigError("a closed-loop scenario needs a CAN port or a pressure_source")
        self.time = 0.0
        self.steps = 0
        self.overruns = 0  # real-time runs: times the loop fell more than max_lag behind
        self.lost_time = 0.0  # [s] real time those overruns dropped (not simulated)
        self.signals: RigSignals | None = None
        self._stop = threading.Event()
        if reset_plant:
            plant.reset(lamella_temperature=scenario.initial_lamella_temperature)

    def stop(self) -> None:
        """Ask a running :meth:`run` to return after the current tick (thread-safe)."""
        self._stop.set()

    def requested_pressure(self, t: float, point=None) -> float:
        """Return the pressure request [Pa] for the step starting at ``t`` [s].

        ``point`` is the scenario's command for that step (default: ``scenario.at(t + dt)``).
        """
        if not self.scenario.closed_loop:
            point = point if point is not None else self.scenario.at(t + self.dt)
            return point.requested_pressure
        if self.port is not None:
            return self.port.requested_pressure(t)
        assert self.pressure_source is not None  # __init__: closed loop needs port or source
        return float(self.pressure_source(t, self.signals))

    def step(self) -> RigSignals:
        """Execute one tick (see the module docstring) and return its signals."""
        t = self.time
        if self.port is not None:
            self.port.poll(t)
        point = self.scenario.at((self.steps + 1) * self.dt)
        request = self.requested_pressure(t, point)
        signals = self.plant.step(self.dt, request, point.slip_speed,
                                  torque_request=point.torque_request)
        self.steps += 1
        self.time = self.steps * self.dt
        self.signals = signals
        lockstep = self.lockstep
        if lockstep is not None and self.steps % lockstep.every == 0:
            lockstep.before_frames(self.time)
            self._send(signals)
            lockstep.after_frames(self.time)
        elif lockstep is None:
            self._send(signals)
        if self.on_step is not None:
            self.on_step(signals)
        return signals

    def _send(self, signals: RigSignals) -> None:
        if self.port is not None:
            stamp = self.stamp_clock() if self.stamp_clock is not None else None
            self.port.send_due(self.time, signals, timestamp=stamp)

    def run(self, duration: float, realtime: bool = True,
            clock: Callable[[], float] = time.monotonic,
            sleep: Callable[[float], None] = time.sleep,
            max_lag: float = 0.1) -> RunStats:
        """Run ticks for ``duration`` [s] of simulation time (``inf``: until ``stop()``).

        Args:
            duration: simulation time to run [s]
            realtime: pace ticks by ``clock`` (seconds, monotonic) and ``sleep``; False runs
                as fast as possible
            clock: monotonic clock [s] used for pacing and ``wall_time``
            sleep: sleep function [s] used for pacing
            max_lag: real-time backlog [s] after which lost time is dropped (an overrun)

        """
        if math.isnan(duration) or duration < 0.0:
            raise RigConfigError(f"duration must be >= 0 s, got {duration!r}")
        self._stop.clear()
        stats = RunStats()
        overruns0 = self.overruns
        sent0 = self.port.sent if self.port is not None else 0
        n_steps = math.inf if math.isinf(duration) else round(duration / self.dt)
        start = clock()
        next_tick = start
        while stats.steps < n_steps:
            if self._stop.is_set():
                stats.stopped = True
                break
            if realtime:
                now = clock()
                if now < next_tick:
                    sleep(next_tick - now)
                    continue
                if now - next_tick > max_lag:
                    self.overruns += 1
                    self.lost_time += now - next_tick
                    next_tick = now
                next_tick += self.dt
            self.step()
            stats.steps += 1
        stats.wall_time = clock() - start
        stats.overruns = self.overruns - overruns0
        stats.sim_time = self.time
        stats.frames_sent = (self.port.sent - sent0) if self.port is not None else 0
        return stats


def run_offline(plant: Any, scenario: Scenario, dt: float = 1e-3,
                duration: float | None = None,
                pressure_source: Callable[[float, Any], float] | None = None
                ) -> dict[str, np.ndarray]:
    """Run ``plant`` through ``scenario`` without a bus; return every signal as an array.

    The plant is reset to the scenario's start temperature. Returns ``{RigSignals field:
    array}`` with one row per step (arrays of arrays become 2-D: ``ff_voltages`` (n, 8),
    ``normal_force`` (n, N) ...). Closed-loop scenarios need ``pressure_source(t [s], last
    RigSignals or None) -> Pa``.
    """
    rows: list[Any] = []
    sim = RigSimulator(plant, scenario, None, dt, pressure_source=pressure_source,
                       on_step=rows.append)
    sim.run(scenario.duration if duration is None else duration, realtime=False)
    if not rows:
        raise RigConfigError("the run is shorter than one step")
    return {f.name: np.array([getattr(r, f.name) for r in rows]) for f in fields(rows[0])}
