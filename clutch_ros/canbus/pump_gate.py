"""Turn PressureCommands into PumpRequest frames, with clamping, rate limit and watchdog.

:class:`PumpCommandGate` is the last line of defence before the pump ECU: whatever arrives
(NaN, inf, negative, huge, nothing at all), every frame it returns requests a pressure within
``[0, max_pressure]`` with a valid rolling counter and checksum, and the returned ``reason``
says why the request differs from the command.

Use: call :meth:`PumpCommandGate.submit` for each PressureCommand and
:meth:`PumpCommandGate.tick` every PumpRequest cycle (10 ms); send the returned frame each
time. Time comes from the ``clock`` passed in (seconds, monotonic), never from the system.

Fail-safe zeroing (no command yet, watchdog, non-finite or negative command) goes to 0 bar at
once; the rate limits apply to ordinary set-point changes only. Zero pressure opens the clutch,
the safe state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import can

from clutch_ros.canbus.dbc import PumpRequestCodec
from clutch_ros.canbus.errors import EncodeError
from clutch_ros.errors import ConfigError

__all__ = ["GateOutput", "PumpCommandGate", "PumpGateConfig"]

_BAR = 1e5  # [Pa]


@dataclass(frozen=True)
class PumpGateConfig:
    """Limits of the pump command path (SI).

    ``max_pressure`` [Pa] (at most the DBC maximum, 60 bar); ``rate_limit_up`` and
    ``rate_limit_down`` [Pa/s] (``math.inf`` = unlimited); ``watchdog_timeout`` [s]: no
    command for longer than this sends 0 bar. Raises
    :class:`clutch_ros.errors.ConfigError` when a value is out of range.
    """

    max_pressure: float = 40.0 * _BAR
    rate_limit_up: float = 200.0 * _BAR
    rate_limit_down: float = math.inf
    watchdog_timeout: float = 0.1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_pressure) and self.max_pressure > 0.0):
            raise ConfigError(f"max_pressure must be > 0 Pa, got {self.max_pressure!r}")
        for name in ("rate_limit_up", "rate_limit_down"):
            value = getattr(self, name)
            if math.isnan(value) or value <= 0.0:
                raise ConfigError(f"{name} must be > 0 Pa/s (inf = none), got {value!r}")
        if not (math.isfinite(self.watchdog_timeout) and self.watchdog_timeout > 0.0):
            raise ConfigError(
                f"watchdog_timeout must be > 0 s, got {self.watchdog_timeout!r}"
            )


class GateOutput(NamedTuple):
    """What the gate decided: the frame to send and the pressure it requests.

    ``pressure`` [Pa] is exactly the (quantized) value in ``frame``; ``limited`` is True when
    it differs from the command for any reason; ``reason`` explains (empty when not limited).
    """

    frame: can.Message
    pressure: float
    limited: bool
    reason: str


class PumpCommandGate:
    """PressureCommand -> PumpRequest frames, never outside limits (see module docstring).

    ``clock`` returns the current time [s] (monotonic); ``codec`` defaults to a
    :class:`PumpRequestCodec` on the default DBC with the configured ``max_pressure``.
    """

    def __init__(
        self,
        clock: Callable[[], float],
        config: PumpGateConfig | None = None,
        codec: PumpRequestCodec | None = None,
    ) -> None:
        self.config = config if config is not None else PumpGateConfig()
        self.codec = (
            codec
            if codec is not None
            else PumpRequestCodec(max_pressure=self.config.max_pressure)
        )
        #: largest pressure a frame may request [Pa]: config and DBC limit, quantized down
        self.max_pressure = self.codec.quantize(
            min(self.config.max_pressure, self.codec.max_pressure)
        )
        if self.max_pressure > self.config.max_pressure:
            self.max_pressure -= self.codec.resolution
        self._clock = clock
        self._counter = 0
        self._target = 0.0
        self._target_reason = "no command yet"
        self._fail_safe = True
        self._last_command: float | None = None
        self._last_time = float(clock())
        self._applied = 0.0  # [Pa] quantized, as sent
        self._ramp = 0.0  # [Pa] exact rate-limited set-point (no quantization stall)
        self._watchdog_tripped = False
        #: number of times the watchdog zeroed the request (once per command gap)
        self.watchdog_trips = 0
        #: commands received / commands replaced by 0 bar (NaN, inf, negative)
        self.commands = 0
        self.rejected_commands = 0
        #: frames produced
        self.frames = 0

    @property
    def applied_pressure(self) -> float:
        """Pressure [Pa] requested by the last frame."""
        return self._applied

    def submit(self, pressure: float) -> GateOutput:
        """Take a commanded ``pressure`` [Pa] and return the frame to send now.

        NaN/inf/negative (or not a number) -> 0 bar with a reason; above the maximum ->
        clamped; the step towards it is rate limited.
        """
        now = float(self._clock())
        self.commands += 1
        self._last_command = now
        self._watchdog_tripped = False
        try:
            value = float(pressure)
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            self.rejected_commands += 1
            self._set_target(0.0, f"command not finite ({value}) -> 0 bar", fail_safe=True)
        elif value < 0.0:
            self.rejected_commands += 1
            self._set_target(
                0.0, f"negative command ({value / _BAR:.3f} bar) -> 0 bar", fail_safe=True
            )
        elif value > self.max_pressure:
            self._set_target(
                self.max_pressure,
                f"clamped {value / _BAR:.3f} bar to max {self.max_pressure / _BAR:.3f} bar",
                fail_safe=False,
            )
        else:
            self._set_target(value, "", fail_safe=False)
        return self._output(now)

    def tick(self) -> GateOutput:
        """Return the periodic frame (call every PumpRequest cycle); checks the watchdog."""
        now = float(self._clock())
        if self._last_command is not None and not self._watchdog_tripped:
            silence = now - self._last_command
            if silence > self.config.watchdog_timeout:
                self._watchdog_tripped = True
                self.watchdog_trips += 1
                self._set_target(
                    0.0,
                    f"watchdog: no command for {silence:.3f} s "
                    f"(timeout {self.config.watchdog_timeout:.3f} s) -> 0 bar",
                    fail_safe=True,
                )
        return self._output(now)

    def _set_target(self, target: float, reason: str, fail_safe: bool) -> None:
        self._target = target
        self._target_reason = reason
        self._fail_safe = fail_safe

    def _output(self, now: float) -> GateOutput:
        dt = max(0.0, now - self._last_time)
        self._last_time = now
        reasons = [self._target_reason] if self._target_reason else []
        target = self._target
        if self._fail_safe:
            applied = target
        else:
            step = target - self._ramp
            up = self.config.rate_limit_up * dt
            down = self.config.rate_limit_down * dt
            applied = self._ramp + min(max(step, -down), up)
            if abs(applied - target) > 0.5 * self.codec.resolution:
                reasons.append(
                    f"rate limited: {applied / _BAR:.3f} bar on the way to "
                    f"{target / _BAR:.3f} bar"
                )
        # Final guard: whatever happened above, the frame stays within [0, max].
        if not math.isfinite(applied):
            applied = 0.0
        self._ramp = min(max(applied, 0.0), self.max_pressure)
        applied = self.codec.quantize(min(max(applied, 0.0), self.max_pressure))
        applied = min(applied, self.max_pressure)
        counter = self._counter
        self._counter = (self._counter + 1) % 16
        try:
            frame = self.codec.encode(applied, counter, timestamp=now)
        except EncodeError as err:  # cannot happen within limits; stay safe regardless
            applied = self._ramp = 0.0
            frame = self.codec.encode(0.0, counter, timestamp=now)
            reasons.append(f"encode failed ({err}) -> 0 bar")
        self._applied = applied
        self.frames += 1
        reason = "; ".join(reasons)
        return GateOutput(frame, applied, bool(reason), reason)
