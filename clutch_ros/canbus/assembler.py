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
10 ms: 10 ms for 1 ms frames, 50 ms for 10 ms frames, 500 ms for RigTemperatures), when it
is required and was never received, when its newest frame held a value outside the DBC
signal's range (that frame is counted as decode error ``range`` and its values are not used:
the sample keeps the group's last valid values, flagged), or when a field it fills is NaN
because it never arrived while a sibling did (``ff_voltages`` with only the rear FlexiForce
frame: the front group is flagged). So every non-finite value of a sample is flagged, and
every flagged group's values are either the last valid ones or NaN. Optional groups never
received and without a sibling are not stale; their arrays stay empty.

Data path: :meth:`RigStateAssembler.feed` decodes a frame and writes its values straight into
the live sample (one dict lookup for the frame key, no re-assembly);
:meth:`RigStateAssembler.snapshot` copies it and sets ``stale_mask``. Frames that are no valid
CAN frame (an 11-bit identifier above 0x7FF, more than 8 bytes without the FD flag, a DLC that
differs from the data length) are counted as decode error ``invalid_frame``.
"""

from __future__ import annotations

import copy
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import can

from clutch_ros.canbus.counters import CounterSnapshot, FrameCounters, classify_socketcan_error
from clutch_ros.canbus.dbc import RigDatabase, counter_gap, frame_key
from clutch_ros.canbus.errors import FrameDecodeError
from clutch_ros.errors import ConfigError
from clutch_ros.rigstate import FF_SIGNALS, FIELDS, WHEEL_SIGNALS, RigSample

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
_FF_MESSAGES = tuple(message for message, _ in FF_SIGNALS)
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
        #: frame key -> its group (rig frames only)
        self._group_of = {self.db.frame(g.message).key: g for g in self.groups}
        self._fill = {key: _filler(g.message) for key, g in self._group_of.items()}
        self._sibling = {"ff_front": "ff_rear", "ff_rear": "ff_front"}
        self._counter_signal = {
            spec.key: spec.counter_signal for spec in self.db.frames if spec.counter_signal
        }
        self._cycle = {spec.key: spec.cycle_time for spec in self.db.frames}
        self._known = self.db.keys
        self._socketcan_errors = socketcan_error_frames
        self._lock = threading.Lock()
        self._counters = FrameCounters()
        self._live = RigSample()
        self._stamps: dict[str, float] = {}  # group -> bus time [s] of its newest valid frame
        self._rejected: set[str] = set()  # groups whose newest frame was out of range
        self._last_counter: dict[int, tuple[float, int]] = {}
        self._newest_time: float | None = None

    # -- input ----------------------------------------------------------------------------

    def feed(self, msg: can.Message) -> int | None:
        """Count one frame and, for a rig data frame, decode it into the live sample.

        Returns the frame key of a data frame (:func:`frame_key`), None for error, remote and
        invalid frames. Never raises for bad frames.
        """
        if msg.is_error_frame:
            with self._lock:
                c = self._counters
                c.frames_total += 1
                c.error_frames += 1
                if self._socketcan_errors:
                    bus_off, overflow = classify_socketcan_error(msg.arbitration_id, msg.data)
                    c.bus_off_frames += bus_off
                    c.controller_overflows += overflow
            return None
        key = frame_key(msg.arbitration_id, msg.is_extended_id)
        valid = _valid_frame(msg)
        values = reason = None
        if valid and not msg.is_remote_frame and key in self._known:
            try:
                values = self.db.decode(msg.arbitration_id, msg.data, msg.is_extended_id)
            except FrameDecodeError as err:
                reason, values = err.reason, err.values
        stamp = float(msg.timestamp)
        with self._lock:
            c = self._counters
            c.frames_total += 1
            if msg.is_fd:
                c.fd_frames += 1
            if msg.is_remote_frame:
                c.remote_frames += 1
                if key in self._known:
                    c.per_id[key] += 1
                return None
            c.data_frames += 1
            if not valid:
                c.decode_errors["invalid_frame"] += 1
                return None
            if key not in self._known:
                c.count_unknown(key)
                return key
            c.per_id[key] += 1
            if reason is not None:
                c.decode_errors[reason] += 1
                if reason == "range":  # an intact frame: its counter still counts
                    self._track_counter(key, stamp, values)
                    group = self._group_of.get(key)
                    if group is not None:
                        self._rejected.add(group.name)
                return key
            c.decoded_frames += 1
            self._track_counter(key, stamp, values)
            if self._newest_time is None or stamp > self._newest_time:
                self._newest_time = stamp
            group = self._group_of.get(key)
            if group is not None:
                self._fill[key](self._live, values)
                self._stamps[group.name] = stamp
                self._rejected.discard(group.name)
        return key

    def _track_counter(self, key: int, stamp: float, values) -> None:
        name = self._counter_signal.get(key)
        if name is None or values is None:
            return
        counter = int(values[name])
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
        """Return a copy of the live :class:`RigSample` with ages and ``stale_mask`` set.

        ``now`` [s] is the current time in the bus time base, used for the age check; when
        None the newest decoded frame's timestamp is used (log replay).
        """
        with self._lock:
            sample = copy.copy(self._live)
            sample.ff_voltages = list(self._live.ff_voltages)
            sample.wheel_speeds = list(self._live.wheel_speeds)
            stamps = dict(self._stamps)
            rejected = set(self._rejected)
            newest = self._newest_time
        if now is None:
            now = newest if newest is not None else 0.0
        sample.ages, sample.stale, sample.stale_mask = {}, [], 0
        for group in self.groups:
            stamp = stamps.get(group.name)
            age = math.inf if stamp is None else max(0.0, now - stamp)
            sample.ages[group.name] = age
            sibling = self._sibling.get(group.name)
            if (
                (stamp is None and (group.required or (sibling in stamps)))
                or (stamp is not None and age > group.max_age)
                or group.name in rejected
            ):
                sample.stale_mask |= 1 << group.bit
                sample.stale.append(group.name)
        sample.stamp = max(stamps.values()) if stamps else None
        if sample.stale_mask & 1:  # pressure_torque stale: no valid measured torque
            sample.has_measured_torque = False
        return sample


def _valid_frame(msg: can.Message) -> bool:
    """Return False for a frame no CAN controller could have sent (see module docstring)."""
    limit = 0x20000000 if msg.is_extended_id else 0x800
    size = len(msg.data)
    if not 0 <= msg.arbitration_id < limit or size > (64 if msg.is_fd else 8):
        return False
    return msg.is_remote_frame or msg.dlc == size


def _scalar_writer(message: str) -> tuple[tuple[str, str], ...]:
    """``(RigState field, DBC signal)`` pairs of the scalars frame ``message`` feeds."""
    return tuple((f.name, f.dbc[1]) for f in FIELDS
                 if f.kind == "scalar" and f.dbc is not None and f.dbc[0] == message)


def _filler(message: str) -> Callable[[RigSample, Mapping[str, float | int]], None]:
    """Return the function that writes the decoded values of ``message`` into a sample."""
    scalars = _scalar_writer(message)

    def write_scalars(sample: RigSample, v: Mapping[str, float | int]) -> None:
        for name, signal in scalars:
            setattr(sample, name, float(v[signal]))

    if message == "RigFast":
        def fill(sample, v):
            write_scalars(sample, v)
            sample.has_measured_torque = bool(v["MeasuredTorqueValid"])
    elif message == "RigSpeed":
        def fill(sample, v):
            write_scalars(sample, v)
            sample.slip_speed = sample.input_speed - sample.output_speed
    elif message == "PumpStatus":
        def fill(sample, v):
            write_scalars(sample, v)
            sample.pump_pressure = float(v["PumpSts_ActualPressure"])
            sample.pump_state = int(v["PumpSts_State"])
            sample.pump_faults = sum(1 << i for i, n in enumerate(_PUMP_FAULTS) if v[n])
    elif message in (_FF_MESSAGES[0], _FF_MESSAGES[1]):
        offset = 4 * _FF_MESSAGES.index(message)
        signals = _FF_FRONT if offset == 0 else _FF_REAR

        def fill(sample, v):
            if not sample.ff_voltages:
                sample.ff_voltages = [_NAN] * 8
            sample.ff_voltages[offset:offset + 4] = [float(v[n]) for n in signals]
    elif message == WHEEL_SIGNALS[0]:
        def fill(sample, v):
            sample.wheel_speeds = [float(v[n]) for n in _WHEELS]
    else:
        fill = write_scalars
    return fill
