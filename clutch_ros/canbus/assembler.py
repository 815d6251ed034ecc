"""Assemble RigState samples from decoded rig frames.

:class:`RigStateAssembler` is a :class:`can.Listener`: hand it to a :class:`can.Notifier`
(its thread calls :meth:`RigStateAssembler.feed`) and call :meth:`RigStateAssembler.snapshot`
from any other thread (the ROS timer). One lock guards the small per-frame update; decoding
happens outside of it. A frame that cannot be decoded is counted and never stops the next.

Signal groups and the ``stale_mask`` bits (one group per DBC frame):

===  ==================  =================  =========  ==================================
bit  group               frame              required   RigState fields
===  ==================  =================  =========  ==================================
0    ``pressure_torque``  RigFast            yes        actuating_pressure, measured_torque
1    ``shaft_speeds``     RigSpeed           yes        input/output/slip_speed
2    ``temperatures``     RigTemperatures    yes        lamella/oil_temperature
3    ``pump_status``      PumpStatus         yes        pump_current (+ pump extras)
4    ``ff_front``         FlexiForceFront    no         ff_voltages[0:4]
5    ``ff_rear``          FlexiForceRear     no         ff_voltages[4:8]
6    ``wheel_speeds``     WheelSpeeds        no         wheel_speeds
7    ``torque_request``   TorqueRequest      no         torque_request
===  ==================  =================  =========  ==================================

A group is stale when it is older than its maximum age (default: 5 cycle times, at least
10 ms: 10 ms for 1 ms frames, 50 ms for 10 ms frames, 500 ms for RigTemperatures), or when it
is required and was never received. Optional groups never received are not stale; their
arrays stay empty.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import can

from clutch_ros.canbus.counters import CounterSnapshot, FrameCounters, classify_socketcan_error
from clutch_ros.canbus.dbc import RigDatabase, counter_gap, frame_key
from clutch_ros.canbus.errors import FrameDecodeError
from clutch_ros.errors import ConfigError
from clutch_ros.rigstate import FF_SIGNALS, WHEEL_SIGNALS, RigSample

__all__ = [
    "DEFAULT_GROUPS",
    "RigSample",
    "RigStateAssembler",
    "SignalGroup",
]


@dataclass(frozen=True)
class SignalGroup:
    """A group of signals sharing one frame: ``bit`` in ``stale_mask``, ``max_age`` [s]."""

    name: str
    message: str
    bit: int
    max_age: float
    required: bool


#: (group name, DBC message, required) in stale_mask bit order.
DEFAULT_GROUPS: tuple[tuple[str, str, bool], ...] = (
    ("pressure_torque", "RigFast", True),
    ("shaft_speeds", "RigSpeed", True),
    ("temperatures", "RigTemperatures", True),
    ("pump_status", "PumpStatus", True),
    ("ff_front", "FlexiForceFront", False),
    ("ff_rear", "FlexiForceRear", False),
    ("wheel_speeds", "WheelSpeeds", False),
    ("torque_request", "TorqueRequest", False),
)

_FF_FRONT, _FF_REAR = (names for _, names in FF_SIGNALS)
_WHEELS = WHEEL_SIGNALS[1]
_PUMP_FAULTS = (
    "PumpSts_FltOverCurrent",
    "PumpSts_FltOverTemp",
    "PumpSts_FltUnderVoltage",
    "PumpSts_FltSensor",
    "PumpSts_FltReqTimeout",
    "PumpSts_FltReqChecksum",
    "PumpSts_FltReqCounter",
)
_NAN = float("nan")




class RigStateAssembler(can.Listener):
    """Keep the latest decoded value of every rig signal and build :class:`RigSample`.

    ``max_ages`` overrides the maximum age [s] of groups by name; ``required`` replaces the
    set of required group names. ``socketcan_error_frames``: error frames carry the SocketCAN
    error class in their identifier (true for the socketcan interface only), so bus-off and
    controller-overflow error frames are counted apart. Raises
    :class:`clutch_ros.errors.ConfigError` for unknown group names or non-positive ages,
    :class:`DbcError` when the DBC lacks a group's frame.
    """

    def __init__(
        self,
        db: RigDatabase | None = None,
        max_ages: Mapping[str, float] | None = None,
        required: Iterable[str] | None = None,
        socketcan_error_frames: bool = False,
    ) -> None:
        self.db = db if db is not None else RigDatabase()
        max_ages = dict(max_ages or {})
        names = {name for name, _, _ in DEFAULT_GROUPS}
        required_set = set(required) if required is not None else None
        for name in set(max_ages) | (required_set or set()):
            if name not in names:
                raise ConfigError(f"unknown signal group {name!r}; known: {sorted(names)}")
        groups = []
        for bit, (name, message, req) in enumerate(DEFAULT_GROUPS):
            spec = self.db.frame(message)
            default_age = max(5.0 * (spec.cycle_time or 0.1), 0.01)
            age = float(max_ages.get(name, default_age))
            if not (math.isfinite(age) and age > 0.0):
                raise ConfigError(f"max age of {name} must be > 0 s, got {age!r}")
            groups.append(
                SignalGroup(
                    name=name,
                    message=message,
                    bit=bit,
                    max_age=age,
                    required=req if required_set is None else name in required_set,
                )
            )
        self.groups: tuple[SignalGroup, ...] = tuple(groups)
        self._group_key = {g.name: self.db.frame(g.message).key for g in self.groups}
        self._counter_signal = {
            spec.key: spec.counter_signal for spec in self.db.frames if spec.counter_signal
        }
        self._cycle = {spec.key: spec.cycle_time for spec in self.db.frames}
        self._known = self.db.keys
        self._socketcan_errors = socketcan_error_frames
        self._lock = threading.Lock()
        self._counters = FrameCounters()
        self._latest: dict[int, tuple[float, dict[str, float | int]]] = {}
        self._last_counter: dict[int, tuple[float, int]] = {}
        self._newest_time: float | None = None

    # -- input ----------------------------------------------------------------------------

    def feed(self, msg: can.Message) -> None:
        """Count and, for known data frames, decode one frame. Never raises for bad frames."""
        values = None
        reason = None
        key = None
        kind = "error" if msg.is_error_frame else "remote" if msg.is_remote_frame else "data"
        if kind == "data":
            key = frame_key(msg.arbitration_id, msg.is_extended_id)
            if key in self._known:
                try:
                    values = self.db.decode(msg.arbitration_id, msg.data, msg.is_extended_id)
                except FrameDecodeError as err:
                    reason = err.reason
        elif kind == "remote":
            key = frame_key(msg.arbitration_id, msg.is_extended_id)
        stamp = float(msg.timestamp)
        with self._lock:
            c = self._counters
            c.frames_total += 1
            if kind == "error":
                c.error_frames += 1
                if self._socketcan_errors:
                    bus_off, overflow = classify_socketcan_error(msg.arbitration_id, msg.data)
                    c.bus_off_frames += bus_off
                    c.controller_overflows += overflow
                return
            c.per_id[key] += 1
            if msg.is_fd:
                c.fd_frames += 1
            if kind == "remote":
                c.remote_frames += 1
                return
            c.data_frames += 1
            if key not in self._known:
                c.unknown_frames += 1
                c.unknown_ids.add(key)
                return
            if values is None:
                c.decode_errors[reason or "payload"] += 1
                return
            c.decoded_frames += 1
            self._latest[key] = (stamp, values)
            if self._newest_time is None or stamp > self._newest_time:
                self._newest_time = stamp
            counter_name = self._counter_signal.get(key)
            if counter_name is not None:
                self._track_counter(key, stamp, int(values[counter_name]))

    def _track_counter(self, key: int, stamp: float, counter: int) -> None:
        last = self._last_counter.get(key)
        self._last_counter[key] = (stamp, counter)
        if last is None:
            return
        cycle = self._cycle.get(key) or 0.0
        if cycle and stamp - last[0] > 16.0 * cycle:
            return  # too long a silence: the 4-bit counter cannot tell what was lost
        if counter == last[1]:
            self._counters.counter_repeats += 1
        else:
            self._counters.dropped_frames += counter_gap(last[1], counter)

    def on_message_received(self, msg: can.Message) -> None:
        """Handle a frame from the Notifier thread: same as :meth:`feed`."""
        self.feed(msg)

    def on_error(self, exc: Exception) -> None:
        """Count an exception of the Notifier thread (handling it keeps the thread running)."""
        with self._lock:
            self._counters.listener_errors += 1

    # -- output ---------------------------------------------------------------------------

    def counters(self) -> CounterSnapshot:
        """Return a consistent copy of the frame counters."""
        with self._lock:
            return self._counters.snapshot()

    def rates(self, now: float) -> tuple[float, dict[int, float]]:
        """Return ``(total, per frame key)`` rates [frames/s] since the previous call.

        ``now`` [s] is a monotonic time of the caller (e.g. ``time.monotonic()``).
        """
        with self._lock:
            return self._counters.rates(now)

    @property
    def newest_time(self) -> float | None:
        """Bus timestamp [s] of the newest decoded frame, None before any."""
        with self._lock:
            return self._newest_time

    def snapshot(self, now: float | None = None) -> RigSample:
        """Build a :class:`RigSample` from the latest values.

        ``now`` [s] is the current time in the bus time base, used for the age check; when
        None the newest decoded frame's timestamp is used (log replay).
        """
        with self._lock:
            latest = {g.name: self._latest.get(self._group_key[g.name]) for g in self.groups}
            newest = self._newest_time
        if now is None:
            now = newest if newest is not None else 0.0
        sample = RigSample()
        for group in self.groups:
            entry = latest[group.name]
            age = math.inf if entry is None else max(0.0, now - entry[0])
            sample.ages[group.name] = age
            if (entry is None and group.required) or (entry is not None and age > group.max_age):
                sample.stale_mask |= 1 << group.bit
                sample.stale.append(group.name)
        stamps = [entry[0] for entry in latest.values() if entry is not None]
        sample.stamp = max(stamps) if stamps else None
        self._fill_values(sample, {k: (v[1] if v else None) for k, v in latest.items()})
        return sample

    @staticmethod
    def _fill_values(sample: RigSample, v: Mapping[str, Mapping[str, float | int] | None]) -> None:
        fast = v["pressure_torque"]
        if fast is not None:
            sample.actuating_pressure = float(fast["ActuatingPressure"])
            sample.measured_torque = float(fast["MeasuredTorque"])
            sample.has_measured_torque = bool(fast["MeasuredTorqueValid"]) and not (
                sample.stale_mask & 1
            )
        speeds = v["shaft_speeds"]
        if speeds is not None:
            sample.input_speed = float(speeds["InputShaftSpeed"])
            sample.output_speed = float(speeds["OutputShaftSpeed"])
            sample.slip_speed = sample.input_speed - sample.output_speed
        temps = v["temperatures"]
        if temps is not None:
            sample.lamella_temperature = float(temps["LamellaTemperature"])
            sample.oil_temperature = float(temps["OilTemperature"])
        pump = v["pump_status"]
        if pump is not None:
            sample.pump_current = float(pump["PumpSts_Current"])
            sample.pump_pressure = float(pump["PumpSts_ActualPressure"])
            sample.pump_state = int(pump["PumpSts_State"])
            sample.pump_faults = sum(
                1 << i for i, name in enumerate(_PUMP_FAULTS) if pump[name]
            )
        front, rear = v["ff_front"], v["ff_rear"]
        if front is not None or rear is not None:
            sample.ff_voltages = [
                float(part[name]) if part is not None else _NAN
                for part, names in ((front, _FF_FRONT), (rear, _FF_REAR))
                for name in names
            ]
        wheels = v["wheel_speeds"]
        if wheels is not None:
            sample.wheel_speeds = [float(wheels[name]) for name in _WHEELS]
        request = v["torque_request"]
        if request is not None:
            sample.torque_request = float(request["TorqueRequest"])
