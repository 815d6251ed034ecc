"""Turn PressureCommands into PumpRequest frames, with clamping, rate limit and watchdog.

:class:`PumpCommandGate` is the last line of defence before the pump ECU: whatever arrives
(NaN, inf, negative, huge, nothing at all), every frame it returns requests a pressure within
``[0, max_pressure]`` with a valid rolling counter and checksum, and the returned ``reason``
says why the request differs from the command.

Use: call :meth:`PumpCommandGate.submit` for each PressureCommand and send the frame it
returns, if any; call :meth:`PumpCommandGate.tick` every PumpRequest cycle (the DBC cycle,
10 ms) and send its frame. Frames leave at the cycle (the latest admitted command each period)
plus at most one immediate frame per period when the request changes, so a publisher at any
rate never makes more than two frames per period and never a backlog.

Admission: a command carries the stamp of its header [s] in the command time base
(``stamp_clock``: the node's clock, so simulated time is honoured). It is refused, counted in
:attr:`PumpCommandGate.refused` by reason, and does not feed the watchdog when it is older
than ``watchdog_timeout`` (``"stale"``), further ahead than ``future_tolerance``
(``"future"``), older than the last admitted command (``"out_of_order"``) or unstamped
(``"unstamped"``, unless ``accept_unstamped``). A node may refuse for reasons of its own
(:meth:`PumpCommandGate.refuse`, e.g. a command from a publisher that is not the configured
source). Time for the watchdog and the rate limit comes from the ``clock`` passed in
(seconds, monotonic), never from the system.

Fail-safe zeroing (no command yet, watchdog, non-finite or negative command) goes to 0 bar at
once; the rate limits apply to ordinary set-point changes only. Zero pressure opens the clutch,
the safe state.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import can

from clutch_ros.canbus.errors import EncodeError
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.errors import ConfigError

__all__ = ["PUMP_PERIOD", "REFUSAL_REASONS", "GateOutput", "PumpCommandGate", "PumpGateConfig"]

#: Why :meth:`PumpCommandGate.submit` refuses a command (``"source"``, ``"inactive"``: refused
#: by the node, for a foreign publisher or while the node is not active).
REFUSAL_REASONS = ("stale", "future", "out_of_order", "unstamped", "source", "inactive")

_BAR = 1e5  # [Pa]

#: [s] the PumpRequest cycle: :meth:`PumpCommandGate.tick` is called this often (the
#: can_bridge's ``pump.period`` default)
PUMP_PERIOD = 0.01


@dataclass(frozen=True)
class PumpGateConfig:
    """Limits of the pump command path (SI).

    ``max_pressure`` [Pa] (at most the DBC maximum, 60 bar); ``rate_limit_up`` and
    ``rate_limit_down`` [Pa/s] (``math.inf`` = unlimited); ``watchdog_timeout`` [s]: no
    admitted command for longer than this sends 0 bar, and a command whose stamp is older
    than this is refused; ``future_tolerance`` [s]: a stamp further ahead of the command
    clock than this is refused; ``accept_unstamped``: admit commands without a stamp;
    ``max_step_interval`` [s]: the longest time between two frames the rate limits credit
    (the bridge passes its ``pump.period``; ``math.inf`` credits all of it).

    The defaults are the configuration the rig runs: the can_bridge node declares its
    ``pump.*`` parameters with these values (:mod:`clutch_ros.nodes.can_bridge_params` reads
    them from here; ``tests/canbus/test_pump_gate.py`` checks that the node's declared defaults
    give exactly this config), so the gate tests test what the node runs. Why these values:

    - ``max_pressure`` 40 bar: the rig's working pressure (the presets' rated point,
      ``params/flexiforce_8.yaml``), below the DBC maximum of 60 bar.
    - ``rate_limit_up`` 400 bar/s (0 to 40 bar in 0.1 s, 4 bar per 10 ms frame): a backstop
      against a runaway command source, not the tuning. Rises below the pump's kick threshold
      (about 100 bar/s, thesis §5.1.1) are the controller's job (``controller.rise_rate_limit``
      90 bar/s); a gate limit below the controller's would bind on every ramp and distort the
      control. Was 200 bar/s here while the node ran 400 bar/s.
    - ``rate_limit_down`` unlimited: a falling pressure opens the clutch, the safe direction.
    - ``watchdog_timeout`` 0.2 s: commands come at 100 Hz (20 missed in a row trip it). The
      same timeout refuses commands stamped older than it, and on a loaded 2-core PC the
      bridge was seen running 80-110 ms late (:mod:`clutch_ros.nodes.can_bridge`), so 0.1 s
      would leave little margin before healthy commands are refused and zeroed. It stays
      below the controller's own input timeouts (0.25 s), and zeroing is the safe side of
      both. Was 0.1 s here while the node ran 0.2 s.
    - ``future_tolerance`` 0.05 s: clock offset between hosts that NTP keeps.
    - ``max_step_interval`` one PumpRequest cycle, :data:`PUMP_PERIOD` (the node passes its
      ``pump.period``, whose default is that cycle). Was ``math.inf`` here (every elapsed
      second credited), which the node never ran.

    Why ``max_step_interval``: crediting the whole elapsed time lets a frame that leaves late
    (a sender stalled for 50 ms on a loaded PC) carry the rise of every period it missed as
    one step. A pump ECU that boosts fast rises (the kick of thesis §5.1.1) reads that step
    as one, and overshoots, although the command never rose faster than the limit. Capped,
    lateness slows the ramp instead: never faster than the limit, never a bigger step than
    one on-time period allows.
    Raises :class:`clutch_ros.errors.ConfigError` when a value is out of range.
    """

    max_pressure: float = 40.0 * _BAR
    rate_limit_up: float = 400.0 * _BAR
    rate_limit_down: float = math.inf
    watchdog_timeout: float = 0.2
    future_tolerance: float = 0.05
    accept_unstamped: bool = False
    max_step_interval: float = PUMP_PERIOD

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
        if math.isnan(self.max_step_interval) or self.max_step_interval <= 0.0:
            raise ConfigError(f"max_step_interval must be > 0 s (inf = none), got "
                              f"{self.max_step_interval!r}")
        if not (math.isfinite(self.future_tolerance) and self.future_tolerance >= 0.0):
            raise ConfigError(
                f"future_tolerance must be >= 0 s, got {self.future_tolerance!r}"
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

    ``clock`` returns the current time [s] (monotonic); ``stamp_clock`` returns the current
    time [s] in the time base of command stamps (default: ``time.time``; a node passes its
    ROS clock); ``codec`` defaults to a :class:`PumpRequestCodec` on the default DBC with the
    configured ``max_pressure``.
    """

    def __init__(
        self,
        clock: Callable[[], float],
        config: PumpGateConfig | None = None,
        codec: PumpRequestCodec | None = None,
        stamp_clock: Callable[[], float] = time.time,
    ) -> None:
        self.config = config if config is not None else PumpGateConfig()
        self.codec = (
            codec
            if codec is not None
            else PumpRequestCodec(max_pressure=self.config.max_pressure)
        )
        #: largest pressure a frame may request [Pa]: config and DBC limit, quantized down
        self.max_pressure = self._max_pressure()
        self._clock = clock
        self._stamp_clock = stamp_clock
        self._last_stamp: float | None = None  # newest admitted stamp (out-of-order check)
        self._command_stamp: float | None = None  # stamp of the last admitted command
        self._immediate_used = False  # an immediate frame went out since the last tick
        self._sent: tuple[float, str] | None = None  # (target, reason) of the last frame
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
        #: commands admitted / admitted commands replaced by 0 bar (NaN, inf, negative)
        self.commands = 0
        self.rejected_commands = 0
        #: commands refused, by reason (:data:`REFUSAL_REASONS`), and the last refusal's text
        self.refused: Counter[str] = Counter()
        self.last_refusal = ""
        #: frames produced / of them, immediate frames on a change (between ticks)
        self.frames = 0
        self.immediate_frames = 0

    def _max_pressure(self) -> float:
        limit = self.codec.quantize(min(self.config.max_pressure, self.codec.max_pressure))
        return limit - self.codec.resolution if limit > self.config.max_pressure else limit

    def reconfigure(self, config: PumpGateConfig) -> None:
        """Apply new limits at once: the next frame (tick or command) obeys them.

        A target above a lowered ``max_pressure`` is clamped now, with the reason; the rate
        limit and the watchdog use the new values from the next frame on.
        """
        self.config = config
        self.max_pressure = self._max_pressure()
        if self._target > self.max_pressure:
            self._set_target(self.max_pressure, f"clamped to max {self.max_pressure / _BAR:.3f} "
                             "bar (pump.max_pressure lowered)", fail_safe=False)

    @property
    def applied_pressure(self) -> float:
        """Pressure [Pa] requested by the last frame."""
        return self._applied

    def submit(self, pressure: float, stamp: float | None = None) -> GateOutput | None:
        """Take a commanded ``pressure`` [Pa] stamped ``stamp`` [s]; return a frame or None.

        Refused commands (see the module docstring) return None and change nothing but the
        counts. An admitted command becomes the target: NaN/inf/negative (or not a number) ->
        0 bar with a reason; above the maximum -> clamped; the step towards it is rate
        limited. The frame is returned at once when the target changed and no immediate frame
        went out since the last :meth:`tick`; otherwise None (the next tick sends it).
        """
        now = self.admit(pressure, stamp)
        if now is None or self._immediate_used \
                or self._sent == (self._target, self._target_reason):
            return None
        self._immediate_used = True
        self.immediate_frames += 1
        return self._output(now)

    def admit(self, pressure: float, stamp: float | None = None) -> float | None:
        """:meth:`submit` without the immediate frame: the next :meth:`tick` sends the target.

        For a sender that takes its commands at each PumpRequest cycle, just before the
        tick. Returns the clock time [s] of the admission, or None when refused (counted).
        """
        refusal = self._admission(stamp)
        if refusal is not None:
            self.refuse(*refusal)
            return None
        now = float(self._clock())
        if stamp is not None:
            self._last_stamp = stamp
        self._command_stamp = stamp
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
        return now

    def _admission(self, stamp: float | None) -> tuple[str, str] | None:
        """Return ``(reason, text)`` when a command stamped ``stamp`` [s] is refused."""
        if stamp is None:
            if self.config.accept_unstamped:
                return None
            return "unstamped", "command refused: no stamp"
        if not math.isfinite(stamp):
            return "unstamped", f"command refused: stamp {stamp} is not finite"
        now = float(self._stamp_clock())
        age = now - stamp
        if age > self.config.watchdog_timeout:
            return "stale", (f"command refused: stamp {age:.3f} s old (more than "
                             f"{self.config.watchdog_timeout:.3f} s)")
        if -age > self.config.future_tolerance:
            return "future", (f"command refused: stamp {-age:.3f} s ahead (more than "
                              f"{self.config.future_tolerance:.3f} s)")
        if self._last_stamp is not None and stamp < self._last_stamp:
            return "out_of_order", (f"command refused: stamp {self._last_stamp - stamp:.6f} s "
                                    "older than the last admitted one")
        return None

    def refuse(self, reason: str, text: str) -> None:
        """Count a refused command (``reason`` for the counts, ``text`` for people); None."""
        self.refused[reason] += 1
        self.last_refusal = text
        return None

    def tick(self) -> GateOutput:
        """Return the periodic frame (call every PumpRequest cycle); checks the watchdog.

        The watchdog trips when no command was admitted for ``watchdog_timeout`` on
        ``clock``, or the last admitted command's stamp is older than that on
        ``stamp_clock`` (a command processed late still expires on time).
        """
        now = float(self._clock())
        self._immediate_used = False
        if self._last_command is not None and not self._watchdog_tripped:
            silence = now - self._last_command
            if self._command_stamp is not None:  # a late-processed command expires on time
                silence = max(silence, float(self._stamp_clock()) - self._command_stamp)
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

    def zero(self, reason: str) -> GateOutput:
        """Return a 0 bar frame at once (fail-safe, e.g. ``"shutdown"``) and keep 0 bar."""
        self._set_target(0.0, f"{reason} -> 0 bar", fail_safe=True)
        self._last_command = None  # no watchdog report to follow: 0 bar already
        return self._output(float(self._clock()))

    def _set_target(self, target: float, reason: str, fail_safe: bool) -> None:
        self._target = target
        self._target_reason = reason
        self._fail_safe = fail_safe

    def _output(self, now: float) -> GateOutput:
        dt = min(max(0.0, now - self._last_time), self.config.max_step_interval)
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
        self._sent = (self._target, self._target_reason)
        self.frames += 1
        reason = "; ".join(reasons)
        return GateOutput(frame, applied, bool(reason), reason)
