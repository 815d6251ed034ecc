"""The rig test sequences of thesis Tables 3 and 4 as sampled time series.

Each :class:`Sequence` holds stamps ``t`` [s] (``k · dt`` from 0), actuating pressure [Pa],
slip speed ω_diff [rad/s] and lamella temperature [°C] (constant: the table's start
temperature; the rig's thermal model heats the lamellas, not this module).

Timing: the table's "time" runs from requesting the pressure increase until requesting 0 bar
again (for PBD: while 40 bar is held). Every sequence starts with ``lead_in`` (default 1 s) at
0 bar and ends with ``lead_out`` (default 3 s, for the rebound to settle) at 0 bar. A pressure
step at time t_s is seen first by the sample after t_s (samples hold the value of the interval
ending at their stamp).

Table 3 (test session 1, "delta before pressure": the slip is established during the lead-in
and held): 1 step 0 → 40 → 0 bar (40 bar for 10 s); 2 incremented step, 8 steps of 10 bar
(10, 20, 30 bar for 3 s each, 40 bar for 6 s, 30, 20, 10 bar for 3 s, 0 at 24 s; the 3 s
grid keeps every switch on a millisecond sample, the thesis does not give the split);
3-5 triangle ramps 0 → 40 → 0 bar in 4, 12, 24 s (half the time up, half down). Slip 10, 30
or 50 rpm, 35 °C.

Table 4 (test session 2, "pressure before delta"): 40 bar held for 10 s; the slip is 0 for
the first second, then a positive step to ω (held 3.5 s), back to 0 for 1 s, a negative step
to −ω (held 3.5 s) and back to 0 for the last second. 10 or 30 rpm, 35 or 60 °C.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from clutch_ros.model.errors import InputError

__all__ = [
    "Sequence",
    "rpm_to_rad_s",
    "step_sequence",
    "incremented_step_sequence",
    "ramp_sequence",
    "pbd_sequence",
    "pbd_release_sequence",
    "table3",
    "table4",
    "make_sequence",
    "concatenate",
    "SEQUENCE_NAMES",
    "BAR",
]

BAR = 1e5  # [Pa]
SEQUENCE_NAMES = ("step", "inc_step", "ramp4", "ramp12", "ramp24", "pbd")


def rpm_to_rad_s(rpm: float) -> float:
    """Convert rev/min to rad/s."""
    return rpm * 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class Sequence:
    """A sampled test sequence (module docstring); arrays of shape (n,)."""

    name: str
    description: str
    t: np.ndarray  # [s]
    actuating_pressure: np.ndarray  # [Pa]
    slip_speed: np.ndarray  # [rad/s]
    lamella_temperature: np.ndarray  # [°C]
    slip_rpm: float
    active: tuple[float, float]  # start and end of the table's time window [s]

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """Sample time [s]."""
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else float("nan")


def _grid(duration: float, dt: float) -> np.ndarray:
    if not (dt > 0.0 and math.isfinite(dt) and duration > 0.0):
        raise InputError(f"need dt > 0 and a positive duration, got dt={dt!r}")
    return np.arange(int(round(duration / dt)) + 1) * dt


def _steps(t: np.ndarray, levels: Iterable[tuple[float, float]]) -> np.ndarray:
    """Piecewise constant: ``levels`` = [(switch time, value), ...] from value 0 at t = 0."""
    out = np.zeros_like(t)
    for t_switch, value in levels:
        out[t > t_switch + 1e-9] = value
    return out


def _make(name: str, description: str, t: np.ndarray, pressure: np.ndarray, slip: np.ndarray,
          temperature: float, slip_rpm: float, active: tuple[float, float]) -> Sequence:
    return Sequence(name, description, t, pressure, slip,
                    np.full(t.shape, float(temperature)), float(slip_rpm), active)


def step_sequence(slip_rpm: float = 10.0, dt: float = 1e-3, *, level: float = 40 * BAR,
                  temperature: float = 35.0, lead_in: float = 1.0,
                  lead_out: float = 3.0) -> Sequence:
    """Table 3 sequence 1: step 0 → ``level`` [Pa] for 10 s → 0, slip held (DBP)."""
    t = _grid(lead_in + 10.0 + lead_out, dt)
    press = _steps(t, [(lead_in, level), (lead_in + 10.0, 0.0)])
    slip = np.full(t.shape, rpm_to_rad_s(slip_rpm))
    return _make("step", "Table 3 seq. 1: step 0-40-0 bar, DBP", t, press, slip, temperature,
                 slip_rpm, (lead_in, lead_in + 10.0))


def incremented_step_sequence(slip_rpm: float = 10.0, dt: float = 1e-3, *,
                              level: float = 40 * BAR, temperature: float = 35.0,
                              lead_in: float = 1.0, lead_out: float = 3.0) -> Sequence:
    """Table 3 sequence 2: 8 steps of ``level``/4 over 24 s (module docstring), DBP."""
    q = level / 4.0
    times = [0, 3, 6, 9, 15, 18, 21, 24]
    values = [q, 2 * q, 3 * q, 4 * q, 3 * q, 2 * q, q, 0.0]
    t = _grid(lead_in + 24.0 + lead_out, dt)
    press = _steps(t, [(lead_in + ts, v) for ts, v in zip(times, values)])
    slip = np.full(t.shape, rpm_to_rad_s(slip_rpm))
    return _make("inc_step", "Table 3 seq. 2: incremented step, 8 steps, DBP", t, press, slip,
                 temperature, slip_rpm, (lead_in, lead_in + 24.0))


def ramp_sequence(duration: float, slip_rpm: float = 10.0, dt: float = 1e-3, *,
                  level: float = 40 * BAR, temperature: float = 35.0, lead_in: float = 1.0,
                  lead_out: float = 3.0, hold_at: tuple[float, ...] = (),
                  hold_time: float = 0.0) -> Sequence:
    """Table 3 sequences 3-5: triangle 0 → ``level`` → 0 over ``duration`` [s], DBP.

    ``hold_at`` (pressures [Pa]) and ``hold_time`` [s] insert plateaus on both legs (to read
    a settled hysteresis); the ramp rate stays level / (duration / 2).
    """
    half = duration / 2.0
    holds = sorted(float(h) for h in hold_at)
    if any(not 0.0 < h < level for h in holds):
        raise InputError(f"hold pressures must lie strictly between 0 and {level!r} Pa")
    knots_t, knots_p = [0.0, lead_in], [0.0, 0.0]
    for i, h in enumerate(holds):  # rising leg
        now = lead_in + half * h / level + i * hold_time
        knots_t += [now, now + hold_time]
        knots_p += [h, h]
    extra = len(holds) * hold_time
    top = lead_in + half + extra
    knots_t.append(top)
    knots_p.append(level)
    for i, h in enumerate(reversed(holds)):  # falling leg
        now = top + half * (level - h) / level + i * hold_time
        knots_t += [now, now + hold_time]
        knots_p += [h, h]
    end = top + half + extra
    total = end + lead_out
    knots_t += [end, total]
    knots_p += [0.0, 0.0]
    t = _grid(total, dt)
    press = np.interp(t, knots_t, knots_p)
    slip = np.full(t.shape, rpm_to_rad_s(slip_rpm))
    name = f"ramp{duration:g}"
    return _make(name, f"Table 3: triangle ramp 0-40-0 bar in {duration:g} s, DBP", t, press,
                 slip, temperature, slip_rpm, (lead_in, end))


def pbd_sequence(slip_rpm: float = 10.0, temperature: float = 35.0, dt: float = 1e-3, *,
                 level: float = 40 * BAR, lead_in: float = 1.0,
                 lead_out: float = 3.0) -> Sequence:
    """Table 4: ``level`` held 10 s, slip steps +ω then −ω (module docstring), PBD."""
    t = _grid(lead_in + 10.0 + lead_out, dt)
    press = _steps(t, [(lead_in, level), (lead_in + 10.0, 0.0)])
    w = rpm_to_rad_s(slip_rpm)
    slip = _steps(t, [(lead_in + 1.0, w), (lead_in + 4.5, 0.0), (lead_in + 5.5, -w),
                      (lead_in + 9.0, 0.0)])
    return _make("pbd", "Table 4: 40 bar held, slip steps +/-, PBD", t, press, slip,
                 temperature, slip_rpm, (lead_in, lead_in + 10.0))


def pbd_release_sequence(slip_rpm: float = 10.0, temperature: float = 35.0,
                         dt: float = 1e-3, *, level: float = 30 * BAR, lead_in: float = 1.0,
                         standstill: float = 1.0, slip_time: float = 2.0, stop: float = 0.5,
                         reverse_time: float = 2.0, lead_out: float = 3.0) -> Sequence:
    """PBD run released while slipping: ``level`` [Pa] at standstill, +ω, stop, −ω, release.

    0 bar for ``lead_in``; ``level`` applied at standstill for ``standstill`` [s]; slip +ω for
    ``slip_time``; 0 for ``stop``; −ω for ``reverse_time``; then the pressure is released to
    0 bar while the −ω slip continues for ``lead_out`` (the open clutch must not transmit).
    """
    w = rpm_to_rad_s(slip_rpm)
    t_on = lead_in
    t_slip = t_on + standstill
    t_stop = t_slip + slip_time
    t_rev = t_stop + stop
    t_off = t_rev + reverse_time
    t = _grid(t_off + lead_out, dt)
    press = _steps(t, [(t_on, level), (t_off, 0.0)])
    slip = _steps(t, [(t_slip, w), (t_stop, 0.0), (t_rev, -w)])
    return _make("pbd_release", "PBD at 30 bar, +/- slip with a stop, released while slipping",
                 t, press, slip, temperature, slip_rpm, (t_on, t_off))


def make_sequence(name: str, slip_rpm: float = 10.0, dt: float = 1e-3,
                  temperature: float = 35.0, **kwargs: Any) -> Sequence:
    """Build a sequence by name: step, inc_step, ramp4, ramp12, ramp24, pbd."""
    if name == "step":
        return step_sequence(slip_rpm, dt, temperature=temperature, **kwargs)
    if name == "inc_step":
        return incremented_step_sequence(slip_rpm, dt, temperature=temperature, **kwargs)
    if name in ("ramp4", "ramp12", "ramp24"):
        return ramp_sequence(float(name[4:]), slip_rpm, dt, temperature=temperature, **kwargs)
    if name == "pbd":
        return pbd_sequence(slip_rpm, temperature, dt, **kwargs)
    if name == "pbd_release":
        return pbd_release_sequence(slip_rpm, temperature, dt, **kwargs)
    raise InputError(f"unknown sequence {name!r} (one of {', '.join(SEQUENCE_NAMES)}, "
                     "pbd_release)")


def table3(slip_rpm: float = 10.0, dt: float = 1e-3) -> list[Sequence]:
    """Test session 1 at one slip speed (10, 30 or 50 rpm): sequences 1-5."""
    return [make_sequence(n, slip_rpm, dt) for n in SEQUENCE_NAMES[:5]]


def table4(dt: float = 1e-3) -> list[Sequence]:
    """Test session 2: PBD at (10 rpm, 35 °C), (10, 60), (30, 35), (30, 60)."""
    return [pbd_sequence(rpm, temp, dt) for rpm, temp in ((10, 35.0), (10, 60.0), (30, 35.0),
                                                          (30, 60.0))]


def concatenate(sequences: list[Sequence], name: str = "concatenated") -> Sequence:
    """Join sequences back to back on one time axis (same dt; stamps stay strictly rising)."""
    if not sequences:
        raise InputError("nothing to concatenate")
    dt = sequences[0].dt
    parts_t, offset = [], 0.0
    for seq in sequences:
        parts_t.append(seq.t + offset)
        offset = parts_t[-1][-1] + dt
    return Sequence(name, " + ".join(s.name for s in sequences), np.concatenate(parts_t),
                    np.concatenate([s.actuating_pressure for s in sequences]),
                    np.concatenate([s.slip_speed for s in sequences]),
                    np.concatenate([s.lamella_temperature for s in sequences]),
                    sequences[0].slip_rpm, (float(parts_t[0][0]), float(parts_t[-1][-1])))
