"""Scripted and closed-loop runs of the simulated rig (thesis §4.3, Tables 3–4).

A scenario says, for every simulation time ``t`` [s], what the rig operator does: the pump
pressure request [Pa], the slip-speed command of the motor [rad/s] and the test host's torque
request [N m] (NaN: none). Schedules are piecewise linear; repeated break times make steps.

Timing convention (the model core's, :mod:`clutch_ros.model.sequences`): ``at(t)`` is the
command held over the step that *ends* at ``t``, and a step at ``t_s`` is first seen by the
step after ``t_s`` (``at`` is left-continuous: at ``t_s`` the old value still holds). With it,
``at(seq.t[k])`` equals the model's sampled Tables 3–4 series at every sample, so golden data
from the rig and the estimator's reference sequences share one time base.

Scripted runs (the rig drives its own pump request, as the thesis' test PC did), each with
``lead_in`` (1 s) at 0 bar before and ``lead_out`` (3 s, for the rebound to settle) after:

* :func:`table3_run` — test session 1, **DBP** (Delta Before Pressure): the slip is on from
  the start (the motor settles during the lead-in) and held to the end. The table's time runs
  from requesting the pressure increase until requesting 0 bar again: 1 step 0→40→0 bar,
  10 s; 2 incremented steps 10/20/30 bar (3 s each), 40 bar (6 s), 30/20/10 bar (3 s each),
  0 at 24 s; 3/4/5 triangle ramps 0→40→0 bar in 4/12/24 s.
* :func:`table4_run` — test session 2, **PBD** (Pressure Before Delta): 40 bar held 10 s; the
  slip is 0 for the first second, then a positive step to +ω_diff (3.5 s), 0 for 1 s, a
  negative step to −ω_diff (3.5 s) and 0 for the last second. Sequences 1–4: 10 rpm/35 °C,
  10 rpm/60 °C, 30 rpm/35 °C, 30 rpm/60 °C start temperature.

Closed loop (:func:`closed_loop_run`): the pressure request comes from outside (pump requests
received on the bus), the slip follows a schedule of rpm segments (default 10 then 30 rpm).

:func:`run_offline` runs a plant through a scenario without any bus and returns arrays.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

from clutch_ros.rig.errors import RigConfigError, check_non_negative, check_positive

__all__ = [
    "ClosedLoopScenario",
    "PiecewiseLinear",
    "Scenario",
    "ScenarioPoint",
    "ScriptedScenario",
    "TABLE3",
    "TABLE4",
    "closed_loop_run",
    "rpm_to_rad_s",

    "scenario_from_spec",
    "table3_run",
    "table4_run",
]

BAR = 1e5  # [Pa]

#: Table 3 sequence -> (description, pressure-sequence duration [s]).
TABLE3 = {1: ("step", 10.0), 2: ("inc step", 24.0), 3: ("ramp 4 s", 4.0),
          4: ("ramp 12 s", 12.0), 5: ("ramp 24 s", 24.0)}
#: Table 4 sequence -> (slip speed [rpm], start lamella temperature [°C]).
TABLE4 = {1: (10.0, 35.0), 2: (10.0, 60.0), 3: (30.0, 35.0), 4: (30.0, 60.0)}


def rpm_to_rad_s(rpm: float) -> float:
    """Convert a speed in rpm to rad/s."""
    return float(rpm) * 2.0 * math.pi / 60.0


class PiecewiseLinear:
    """A left-continuous piecewise-linear function of time, constant outside its breaks.

    ``times`` [s] must be non-decreasing; a repeated time is a step, whose new value holds
    just *after* the step time (see the module's timing convention).
    """

    def __init__(self, times: Sequence[float], values: Sequence[float]) -> None:
        self.times = [float(t) for t in times]
        self.values = [float(v) for v in values]
        if not self.times or len(self.times) != len(self.values):
            raise RigConfigError("a schedule needs as many values as times (at least one)")
        if any(not math.isfinite(x) for x in self.times + self.values):
            raise RigConfigError("schedule times and values must be finite")
        if any(b < a for a, b in zip(self.times, self.times[1:])):
            raise RigConfigError("schedule times must be non-decreasing")

    @classmethod
    def steps(cls, changes: Sequence[tuple[float, float]], initial: float = 0.0
              ) -> PiecewiseLinear:
        """Build a step-held schedule from ``(time [s], new value)`` changes.

        A change at time 0 applies from the first step on (nothing is before it).
        """
        times, values = [-1.0], [float(initial)]
        for t, v in changes:
            times += [t, t]
            values += [values[-1], v]
        return cls(times, values)

    def __call__(self, t: float) -> float:
        """Return the value at ``t`` [s]."""
        times, values = self.times, self.values
        i = bisect.bisect_left(times, t)
        if i == 0:
            return values[0]
        if i == len(times):
            return values[-1]
        t0, t1 = times[i - 1], times[i]  # t0 < t <= t1
        return values[i - 1] + (values[i] - values[i - 1]) * (t - t0) / (t1 - t0)

    @property
    def end(self) -> float:
        """Time of the last break [s]."""
        return self.times[-1]


@dataclass(frozen=True)
class ScenarioPoint:
    """What the operator does at one instant (SI units).

    ``requested_pressure`` [Pa] (NaN in closed loop: it comes from the bus),
    ``slip_speed`` command [rad/s], ``torque_request`` [N m] (NaN: none).
    """

    requested_pressure: float
    slip_speed: float
    torque_request: float


class Scenario:
    """Base of the scenarios: ``at(t)`` plus a name, duration [s] and start temperature [°C].

    With ``repeat`` the schedule restarts every ``duration`` seconds.
    """

    closed_loop = False

    def __init__(self, name: str, duration: float, initial_lamella_temperature: float = 35.0,
                 repeat: bool = False) -> None:
        self.name = name
        self.duration = check_positive("scenario duration", duration)
        self.initial_lamella_temperature = float(initial_lamella_temperature)
        if not math.isfinite(self.initial_lamella_temperature):
            raise RigConfigError("initial lamella temperature must be finite [°C]")
        self.repeat = bool(repeat)

    def _local(self, t: float) -> float:
        return math.fmod(t, self.duration) if self.repeat and t >= self.duration else t

    def at(self, t: float) -> ScenarioPoint:
        """Return the operator's commands at simulation time ``t`` [s]."""
        raise NotImplementedError


class ScriptedScenario(Scenario):
    """Pressure request, slip and (optional) torque request all scripted."""

    def __init__(self, name: str, pressure: PiecewiseLinear, slip: PiecewiseLinear,
                 torque: PiecewiseLinear | None = None, duration: float | None = None,
                 initial_lamella_temperature: float = 35.0, repeat: bool = False) -> None:
        ends = [pressure.end, slip.end] + ([torque.end] if torque else [])
        super().__init__(name, duration if duration is not None else max(ends),
                         initial_lamella_temperature, repeat)
        self.pressure, self.slip, self.torque = pressure, slip, torque

    def at(self, t: float) -> ScenarioPoint:
        """Return the scripted request [Pa], slip [rad/s] and torque request [N m] at ``t``."""
        t = self._local(t)
        torque = self.torque(t) if self.torque is not None else math.nan
        return ScenarioPoint(self.pressure(t), self.slip(t), torque)


class ClosedLoopScenario(Scenario):
    """Slip (and optional torque request) scripted; the pressure request comes from the bus."""

    closed_loop = True

    def __init__(self, name: str, slip: PiecewiseLinear, torque: PiecewiseLinear | None = None,
                 duration: float | None = None, initial_lamella_temperature: float = 35.0,
                 repeat: bool = False) -> None:
        ends = [slip.end] + ([torque.end] if torque else [])
        super().__init__(name, duration if duration is not None else max(ends),
                         initial_lamella_temperature, repeat)
        self.slip, self.torque = slip, torque

    def at(self, t: float) -> ScenarioPoint:
        """Return NaN for the pressure, the slip [rad/s] and torque request [N m] at ``t``."""
        t = self._local(t)
        torque = self.torque(t) if self.torque is not None else math.nan
        return ScenarioPoint(math.nan, self.slip(t), torque)


def _table3_pressure(sequence: int, start: float, peak: float) -> PiecewiseLinear:
    _, length = TABLE3[sequence]
    end = start + length
    if sequence == 1:
        return PiecewiseLinear.steps([(start, peak), (end, 0.0)])
    if sequence == 2:
        levels = [0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25, 0.0]
        changes = [0.0, 3.0, 6.0, 9.0, 15.0, 18.0, 21.0, 24.0]
        return PiecewiseLinear.steps([(start + c, peak * lv) for c, lv in zip(changes, levels)])
    return PiecewiseLinear([0.0, start, start + 0.5 * length, end], [0.0, 0.0, peak, 0.0])


def table3_run(sequence: int, rpm: float, lead_in: float = 1.0, lead_out: float = 3.0,
               peak_pressure: float = 40 * BAR,
               lamella_temperature: float = 35.0) -> ScriptedScenario:
    """Return a Table 3 (test session 1, DBP) run: ``sequence`` 1–5 at ``rpm`` (10/30/50).

    Args:
        sequence: 1 step, 2 incremented steps, 3/4/5 ramps of 4/12/24 s
        rpm: slip speed ω_diff [rpm], on from the start to the end
        lead_in: time before the pressure sequence starts [s]
        lead_out: time after the request returned to 0 bar [s]
        peak_pressure: the 40 bar of the table [Pa]
        lamella_temperature: start temperature [°C] (35 in the table)

    """
    if sequence not in TABLE3:
        raise RigConfigError(f"Table 3 has sequences 1..5, got {sequence!r}")
    check_positive("rpm", rpm)
    check_non_negative("lead_in", lead_in)
    check_non_negative("lead_out", lead_out)
    check_positive("peak_pressure", peak_pressure)
    pressure = _table3_pressure(sequence, lead_in, peak_pressure)
    slip = PiecewiseLinear.steps([(0.0, rpm_to_rad_s(rpm))])
    return ScriptedScenario(f"table3_seq{sequence}_{rpm:g}rpm", pressure, slip,
                            duration=lead_in + TABLE3[sequence][1] + lead_out,
                            initial_lamella_temperature=lamella_temperature)


def table4_run(sequence: int, lead_in: float = 1.0, lead_out: float = 3.0,
               pressure: float = 40 * BAR) -> ScriptedScenario:
    """Return a Table 4 (test session 2, PBD) run, ``sequence`` 1–4 (see module docstring).

    ``pressure`` [Pa] is held for 10 s from ``lead_in`` [s]; the run ends ``lead_out`` [s]
    after the release.
    """
    if sequence not in TABLE4:
        raise RigConfigError(f"Table 4 has sequences 1..4, got {sequence!r}")
    check_non_negative("lead_in", lead_in)
    check_non_negative("lead_out", lead_out)
    check_positive("pressure", pressure)
    rpm, temperature = TABLE4[sequence]
    w = rpm_to_rad_s(rpm)
    request = PiecewiseLinear.steps([(lead_in, float(pressure)), (lead_in + 10.0, 0.0)])
    slip = PiecewiseLinear.steps([(lead_in + 1.0, w), (lead_in + 4.5, 0.0),
                                  (lead_in + 5.5, -w), (lead_in + 9.0, 0.0)])
    return ScriptedScenario(f"table4_seq{sequence}_{rpm:g}rpm_{temperature:g}C", request, slip,
                            duration=lead_in + 10.0 + lead_out,
                            initial_lamella_temperature=temperature)


def closed_loop_run(slip_rpm: Sequence[float] = (10.0, 30.0), segment: float = 10.0,
                    lead: float = 1.0, rest: float = 1.0,
                    torque_steps: Sequence[tuple[float, float]] | None = None,
                    lamella_temperature: float = 35.0, repeat: bool = False
                    ) -> ClosedLoopScenario:
    """Return a closed-loop run: slip 0 for ``lead`` s, each of ``slip_rpm`` for ``segment`` s.

    Args:
        slip_rpm: slip speeds of the consecutive segments [rpm]
        segment: length of each segment [s]
        lead: time at 0 rpm before the first segment [s]
        rest: time at 0 rpm after the last segment [s]
        torque_steps: optional test-host torque request, ``(time [s], torque [N m])``
            changes from 0 N m; None sends no torque request
        lamella_temperature: start temperature [°C]
        repeat: restart the schedule after its end (for a long-running node)

    """
    check_positive("segment", segment)
    check_non_negative("lead", lead)
    check_non_negative("rest", rest)
    changes = [(lead + i * segment, rpm_to_rad_s(rpm)) for i, rpm in enumerate(slip_rpm)]
    end = lead + len(changes) * segment
    slip = PiecewiseLinear.steps(changes + [(end, 0.0)])
    torque = PiecewiseLinear.steps(list(torque_steps)) if torque_steps is not None else None
    rpms = "_".join(f"{r:g}" for r in slip_rpm)
    return ClosedLoopScenario(f"closed_loop_{rpms}rpm", slip, torque, duration=end + rest,
                              initial_lamella_temperature=lamella_temperature, repeat=repeat)


def scenario_from_spec(spec: str, repeat: bool = False) -> Scenario:
    """Build a scenario from a one-line spec (a node parameter).

    Forms: ``table3:SEQ:RPM`` (``table3:5:10``), ``table4:SEQ`` (``table4:2``),
    ``closed_loop`` or ``closed_loop:RPM,RPM,...[:SEGMENT_S]`` (``closed_loop:10,30:20``).
    ``repeat`` restarts the schedule at its end. Raises :class:`RigConfigError` when invalid.
    """
    parts = str(spec).strip().split(":")
    kind, args = parts[0], parts[1:]
    try:
        if kind == "table3" and len(args) == 2:
            sc: Scenario = table3_run(int(args[0]), float(args[1]))
        elif kind == "table4" and len(args) == 1:
            sc = table4_run(int(args[0]))
        elif kind == "closed_loop" and len(args) <= 2:
            rpms = tuple(float(r) for r in args[0].split(",")) if args else (10.0, 30.0)
            segment = float(args[1]) if len(args) == 2 else 10.0
            return closed_loop_run(rpms, segment=segment, repeat=repeat)
        else:
            raise ValueError("unknown form")
    except ValueError as err:
        raise RigConfigError(f"bad rig scenario {spec!r} ({err}); expected table3:SEQ:RPM, "
                             "table4:SEQ or closed_loop[:RPM,RPM,...[:SEGMENT_S]]") from err
    sc.repeat = bool(repeat)
    return sc
