"""Actuation pump of the simulated rig: lag, rate limit, pressure limit and the "kick".

The thesis rig actuates the lamella pack with an electric pump whose ECU follows pressure
requests received on CAN (§4.3.3). The pressure does not follow a request exactly (§4.1): it
lags, rises at a finite rate, and on fast positive requests the ECU deliberately overshoots —
the pressure "kick" of §5.1.1, "programmed ... to compensate for the slower mechanical response
of the clutch and to reach a desired state of compression faster".

Shape of the model, evaluated once per step of length ``dt`` [s] (all pressures in Pa):

1. **Request conditioning** — NaN/negative requests become 0 Pa, requests above
   ``max_pressure`` are clamped (the ECU's limit).
2. **Kick trigger** — the request is smoothed by a first-order filter (time constant
   ``kick_detect_time_constant``) and differentiated. While the smoothed request rises faster
   than ``kick_rate_threshold`` [Pa/s], every increase of the smoothed request excites the kick
   generator. Smoothing makes the trigger see a CAN request staircase (0.2 bar every 10 ms on a
   20 bar/s ramp) as the ramp it is, while a step of a few bar or more still fires it.
3. **Kick shape** — the generator is a critically damped second-order system whose impulse
   response is the pulse ``h(t) = (t/τk)·exp(1 − t/τk)`` (peak 1 at ``t = τk =
   kick_time_constant``). An increase ``Δ`` of the request adds ``kick_gain·Δ·h(t)`` to the
   ECU's internal pressure target, capped at ``kick_max`` [Pa]. Superposition holds, so each step
   of an incremented-step sequence gets its own, smaller kick; ramps below the threshold get
   none; releases never kick.
4. **Rate limit** — the boosted target is followed by a reference that rises at most at
   ``slew_rate`` and falls at most at ``release_slew_rate`` [Pa/s] (pump flow / valve limits).
5. **Lag** — the actual pressure is that reference through a first-order lag with time
   constant ``time_constant`` [s] (exact zero-order-hold discretisation), then clamped to
   ``[0, max_pressure]``.

With the defaults a 0 → 40 bar step peaks at about 44.8 bar (+12 %) near 0.36 s and is back
within 2 % of 40 bar after 0.8 s; each 10 bar step of an incremented-step run overshoots by
about 0.8 bar; a 2 s ramp to 40 bar (Table 3, sequence 3), even as a 100 Hz CAN staircase,
shows no kick.

**Pump current** [A] = ``current_idle`` + ``current_per_pressure``·p + ``current_per_rate``
·max(dp/dt, 0), clamped to ``[0, current_max]``: holding pressure costs motor torque
(∝ p), building it costs flow (∝ dp/dt into the piston chamber's compliance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clutch_ros.rig.errors import RigConfigError, check_non_negative, check_positive

__all__ = ["PumpModel", "PumpParams"]

_E = math.e


@dataclass(frozen=True)
class PumpParams:
    """Parameters of :class:`PumpModel` (SI units).

    Attributes:
        time_constant: first-order pressure lag [s]; 0 disables the lag (default 0.05 s, a
            small gear pump filling a piston chamber)
        slew_rate: maximum pressure rise rate [Pa/s] (default 2e7 Pa/s = 200 bar/s; inf
            disables)
        release_slew_rate: maximum pressure fall rate [Pa/s] (default 4e7 Pa/s = 400 bar/s,
            the release valve is faster than the pump; inf disables)
        max_pressure: largest pressure the ECU produces [Pa] (default 6e6 Pa = 60 bar, the
            PumpRequest range of rig.dbc)
        kick_gain: kick peak as a fraction of a fast request increase [-] (default 0.2;
            0 disables the kick)
        kick_max: cap on the kick's addition to the target [Pa] (default 8e5 Pa = 8 bar)
        kick_time_constant: time from trigger to kick peak, τk [s] (default 0.15 s)
        kick_rate_threshold: smoothed request rise rate above which the kick fires [Pa/s]
            (default 1e7 Pa/s = 100 bar/s; the thesis' slowest "fast" request is a step)
        kick_detect_time_constant: smoothing of the request before differentiation [s]
            (default 0.02 s, two CAN request periods)
        current_idle: pump current at 0 Pa and no flow [A] (default 0.5 A)
        current_per_pressure: current per pressure held [A/Pa] (default 2e-6 A/Pa =
            0.2 A/bar, 8.5 A at 40 bar)
        current_per_rate: current per pressure rise rate [A s/Pa] (default 2e-7 = 0.02 A per
            bar/s, +4 A at the 200 bar/s slew limit)
        current_max: current limit of the pump driver [A] (default 25 A)

    """

    time_constant: float = 0.05
    slew_rate: float = 2.0e7
    release_slew_rate: float = 4.0e7
    max_pressure: float = 6.0e6
    kick_gain: float = 0.2
    kick_max: float = 8.0e5
    kick_time_constant: float = 0.15
    kick_rate_threshold: float = 1.0e7
    kick_detect_time_constant: float = 0.02
    current_idle: float = 0.5
    current_per_pressure: float = 2.0e-6
    current_per_rate: float = 2.0e-7
    current_max: float = 25.0

    def __post_init__(self) -> None:
        check_non_negative("pump.time_constant", self.time_constant)
        check_positive("pump.slew_rate", self.slew_rate, allow_inf=True)
        check_positive("pump.release_slew_rate", self.release_slew_rate, allow_inf=True)
        check_positive("pump.max_pressure", self.max_pressure)
        check_non_negative("pump.kick_gain", self.kick_gain)
        check_non_negative("pump.kick_max", self.kick_max, allow_inf=True)
        check_positive("pump.kick_time_constant", self.kick_time_constant)
        check_non_negative("pump.kick_rate_threshold", self.kick_rate_threshold)
        check_positive("pump.kick_detect_time_constant", self.kick_detect_time_constant)
        check_non_negative("pump.current_idle", self.current_idle)
        check_non_negative("pump.current_per_pressure", self.current_per_pressure)
        check_non_negative("pump.current_per_rate", self.current_per_rate)
        check_positive("pump.current_max", self.current_max)


class PumpModel:
    """Pressure-controlled actuation pump: lag, rate limit, max pressure, kick, current.

    ``step(dt, requested_pressure)`` advances the pump by ``dt`` [s] holding the request
    [Pa] constant over the step and returns ``(actual_pressure [Pa], current [A])``. The
    model is deterministic; sensor noise is added by the plant.
    """

    def __init__(self, params: PumpParams | None = None) -> None:
        self.params = params or PumpParams()
        self._dt_cache: tuple[float, float, float, float] | None = None
        self.reset()

    def reset(self, pressure: float = 0.0) -> None:
        """Reset to a settled state at ``pressure`` [Pa] (request = actual, no kick)."""
        p = min(max(float(pressure), 0.0), self.params.max_pressure)
        self._pressure = p
        self._reference = p
        self._smoothed_request = p
        self._kick_z1 = 0.0
        self._kick_z2 = 0.0
        self._kick = 0.0
        self._current = self._current_for(p, 0.0)

    @property
    def pressure(self) -> float:
        """Actual (outlet) pressure after the last step [Pa]."""
        return self._pressure

    @property
    def current(self) -> float:
        """Pump current after the last step [A]."""
        return self._current

    @property
    def kick(self) -> float:
        """Kick currently added to the ECU's pressure target [Pa] (0 when idle)."""
        return self._kick

    @property
    def reference(self) -> float:
        """Rate-limited internal pressure reference after the last step [Pa]."""
        return self._reference

    def _factors(self, dt: float) -> tuple[float, float, float, float]:
        cache = self._dt_cache
        if cache is not None and cache[0] == dt:
            return cache
        p = self.params
        lag = 1.0 - math.exp(-dt / p.time_constant) if p.time_constant > 0.0 else 1.0
        detect = 1.0 - math.exp(-dt / p.kick_detect_time_constant)
        decay = math.exp(-dt / p.kick_time_constant)
        self._dt_cache = (dt, lag, detect, decay)
        return self._dt_cache

    def _current_for(self, pressure: float, rate: float) -> float:
        p = self.params
        current = (p.current_idle + p.current_per_pressure * pressure
                   + p.current_per_rate * max(rate, 0.0))
        return min(max(current, 0.0), p.current_max)

    def step(self, dt: float, requested_pressure: float) -> tuple[float, float]:
        """Advance by ``dt`` [s] under ``requested_pressure`` [Pa].

        Returns:
            ``(actual_pressure [Pa], current [A])`` at the end of the step.

        Raises:
            RigConfigError: ``dt`` is not a positive finite number.

        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise RigConfigError(f"pump step dt must be positive and finite, got {dt!r}")
        p = self.params
        _, lag, detect, decay = self._factors(dt)
        request = float(requested_pressure)
        if not request > 0.0:  # NaN or <= 0: the ECU releases
            request = 0.0
        request = min(request, p.max_pressure)

        # 2. kick trigger on the smoothed request's rise rate
        previous = self._smoothed_request
        self._smoothed_request = previous + (request - previous) * detect
        rise = self._smoothed_request - previous
        impulse = p.kick_gain * rise if rise > p.kick_rate_threshold * dt else 0.0

        # 3. critically damped kick generator, exact discretisation of
        #    z1' = -z1/tk (+ impulses), z2' = (z1 - z2)/tk; kick = e*z2
        z1, z2 = self._kick_z1 + impulse, self._kick_z2
        self._kick_z2 = decay * (z2 + (dt / p.kick_time_constant) * z1)
        self._kick_z1 = decay * z1
        self._kick = min(_E * self._kick_z2, p.kick_max)
        target = min(request + self._kick, p.max_pressure)

        # 4. rate limit of the reference
        delta = target - self._reference
        delta = min(max(delta, -p.release_slew_rate * dt), p.slew_rate * dt)
        self._reference += delta

        # 5. first-order lag (exact for a reference held over the step)
        old = self._pressure
        new = old + (self._reference - old) * lag
        new = min(max(new, 0.0), p.max_pressure)
        self._pressure = new
        self._current = self._current_for(new, (new - old) / dt)
        return new, self._current
