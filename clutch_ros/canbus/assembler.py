"""Assemble RigState samples from decoded rig frames.

:class:`RigStateAssembler` is a :class:`can.Listener`: hand it to a :class:`can.Notifier`
(its thread calls :meth:`RigStateAssembler.feed`) and call :meth:`RigStateAssembler.snapshot`
from any other thread (the ROS timer). One lock guards the small per-frame update; decoding
happens outside of it. A frame that cannot be decoded is counted and never stops the next.

Signal groups and the ``stale_mask`` bits (:data:`clutch_ros.canbus.signal_map.GROUPS`; the
frames are those the signal map names, here the default map of ``params/rig.dbc``):

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

A group fed by several frames (a rig DBC may put pressure and torque in two messages) is as old
as its oldest frame and stale while one of them is missing; a group the map leaves unmapped is
never stale. A group is stale when it is older than its maximum age (default: 5 cycle times, at
least 10 ms: 10 ms for 1 ms frames, 50 ms for 10 ms frames, 500 ms for RigTemperatures), when it
is required and was never received, when its newest frame held a value outside the DBC signal's
range (that frame is counted as decode error ``range`` and its values are not used: the sample
keeps the group's last valid values, flagged), or when a field it fills is NaN because it never
arrived while a sibling did (``ff_voltages`` with only the rear FlexiForce frame: the front
group is flagged). So every non-finite value of a sample is flagged, and every flagged group's
values are either the last valid ones or NaN. Optional groups never received and without a
sibling are not stale; their arrays stay empty.

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
from clutch_ros.canbus.dbc import CAN_EFF_FLAG, RigDatabase, counter_gap
from clutch_ros.canbus.errors import FrameDecodeError
from clutch_ros.canbus.fastdecode import FastDecoder
from clutch_ros.canbus.signal_map import GROUPS, ResolvedMap, SignalMap, Write
from clutch_ros.errors import ConfigError
from clutch_ros.rigstate import FIELDS, RigSample

__all__ = [
    "ARRAY_LEN",
    "PUMP_FAULTS",
    "SPECIAL_FIELDS",
    "RigSample",
    "RigStateAssembler",
    "SignalGroup",
]


@dataclass(frozen=True)
class SignalGroup:
    """A group of signals: ``bit`` in ``stale_mask``, ``max_age`` [s], its DBC ``messages``."""

    name: str
    messages: tuple[str, ...]
    bit: int
    max_age: float
    required: bool

    @property
    def message(self) -> str:
        """The first DBC message of the group ("" when the map leaves it unmapped)."""
        return self.messages[0] if self.messages else ""


#: length of each array field of RigSample
ARRAY_LEN = {f.name: len(f.csv_stems) for f in FIELDS if f.kind == "array"}
#: the pump status frame's fault flags, bit i of ``pump_faults``
PUMP_FAULTS = (
    "PumpSts_FltOverCurrent",
    "PumpSts_FltOverTemp",
    "PumpSts_FltUnderVoltage",
    "PumpSts_FltSensor",
    "PumpSts_FltReqTimeout",
    "PumpSts_FltReqChecksum",
    "PumpSts_FltReqCounter",
)
_NAN = float("nan")
#: fields the signal map writes with their own rule (not ``mult * value + offset``)
SPECIAL_FIELDS = frozenset({"has_measured_torque", "pump_state"})


class RigStateAssembler(can.Listener):
    """Keep the latest decoded value of every rig signal and build :class:`RigSample`.

    ``max_ages`` overrides the maximum age [s] of groups by name; ``required`` replaces the
    set of required group names. ``socketcan_error_frames``: error frames carry the SocketCAN
    error class in their identifier (true for the socketcan interface only), so bus-off and
    controller-overflow error frames are counted apart. Raises
    :class:`clutch_ros.errors.ConfigError` for unknown group names or non-positive ages,
    :class:`DbcError` when the DBC lacks a frame or signal of ``signal_map`` (default: the
    map of ``params/rig.dbc``, :class:`~clutch_ros.canbus.signal_map.SignalMap`).
    """

    def __init__(
        self,
        db: RigDatabase | None = None,
        max_ages: Mapping[str, float] | None = None,
        required: Iterable[str] | None = None,
        socketcan_error_frames: bool = False,
        signal_map: SignalMap | None = None,
    ) -> None:
        self.db = db if db is not None else RigDatabase()
        #: the signal map checked against the DBC (also gives the pump request codec)
        self.map: ResolvedMap = (signal_map or SignalMap.default()).resolve(self.db)
        max_ages = dict(max_ages or {})
        names = {name for name, _, _ in GROUPS}
        required_set = set(required) if required is not None else None
        for name in set(max_ages) | (required_set or set()):
            if name not in names:
                raise ConfigError(f"unknown signal group {name!r}; known: {sorted(names)}")
        groups = []
        for bit, (name, keys, req) in enumerate(GROUPS):
            messages = self.map.group_messages(keys)
            cycle = max((self.db.frame(m).cycle_time or 0.1 for m in messages), default=0.1)
            age = float(max_ages.get(name, max(5.0 * cycle, 0.01)))
            if not (math.isfinite(age) and age > 0.0):
                raise ConfigError(f"max age of {name} must be > 0 s, got {age!r}")
            groups.append(SignalGroup(name=name, messages=messages, bit=bit, max_age=age,
                                      required=req if required_set is None
                                      else name in required_set))
        self.groups: tuple[SignalGroup, ...] = tuple(groups)
        #: frame key -> the writer of its mapped signals (rig frames only)
        self._fill = {key: _filler(writes) for key, writes in self.map.writes.items()}
        #: group name -> keys of its frames
        self._group_keys = {g.name: tuple(self.db.frame(m).key for m in g.messages)
                            for g in self.groups}
        self._sibling = {"ff_front": "ff_rear", "ff_rear": "ff_front"}
        self._counter_signal = {
            spec.key: spec.counter_signal for spec in self.db.frames if spec.counter_signal
        }
        self._cycle = {spec.key: spec.cycle_time for spec in self.db.frames}
        self._known = self.db.keys
        #: decodes a known frame key's payload (compiled tables; cantools for the rest)
        self.decoder = FastDecoder(self.db)
        self._decode = self.decoder.decode
        self._socketcan_errors = socketcan_error_frames
        self._lock = threading.Lock()
        self._counters = FrameCounters()
        self._live = RigSample()
        self._stamps: dict[int, float] = {}  # rig frame key -> bus time [s] of its newest valid
        self._rejected: set[int] = set()  # rig frame keys whose newest frame was out of range
        self._last_counter: dict[int, tuple[float, int]] = {}
        self._newest_time: float | None = None

    # -- input ----------------------------------------------------------------------------

    def feed(self, msg: can.Message) -> int | None:
        """Count one frame and, for a rig data frame, decode it into the live sample.

        Returns the frame key of a data frame (:func:`frame_key`), None for error, remote and
        invalid frames. Never raises for bad frames.
        """
        return self.feed_frame(float(msg.timestamp), msg.arbitration_id, msg.is_extended_id,
                               msg.is_remote_frame, msg.is_error_frame, msg.is_fd, msg.dlc,
                               msg.data)

    def feed_frame(self, stamp: float, arbitration_id: int, is_extended: bool,
                   is_remote: bool, is_error: bool, is_fd: bool, dlc: int,
                   data: bytes | bytearray) -> int | None:
        """:meth:`feed` for a frame given by its fields (no :class:`can.Message` needed).

        The fields of :data:`clutch_ros.canbus.batch.RawFrame`, in its order: bus time
        ``stamp`` [s], identifier, flags, DLC and payload.
        """
        if is_error:
            with self._lock:
                c = self._counters
                c.frames_total += 1
                c.error_frames += 1
                if self._socketcan_errors:
                    bus_off, overflow = classify_socketcan_error(arbitration_id, data)
                    c.bus_off_frames += bus_off
                    c.controller_overflows += overflow
            return None
        key = arbitration_id | CAN_EFF_FLAG if is_extended else arbitration_id
        size = len(data)
        valid = (0 <= arbitration_id < (0x20000000 if is_extended else 0x800)
                 and size <= (64 if is_fd else 8) and (is_remote or dlc == size))
        known = key in self._known
        values: dict[str, float | int] | None = None
        reason: str | None = None
        if valid and known and not is_remote:
            try:
                values = self._decode(key, data)
            except FrameDecodeError as err:
                reason, values = err.reason, err.values
        with self._lock:
            c = self._counters
            c.frames_total += 1
            if is_fd:
                c.fd_frames += 1
            if is_remote:
                c.remote_frames += 1
                if known:
                    c.per_id[key] += 1
                return None
            c.data_frames += 1
            if not valid:
                c.decode_errors["invalid_frame"] += 1
                return None
            if not known:
                c.count_unknown(key)
                return key
            c.per_id[key] += 1
            if reason is not None:
                c.decode_errors[reason] += 1
                if reason == "range":  # an intact frame: its counter still counts
                    self._track_counter(key, stamp, values)
                    if key in self._fill:
                        self._rejected.add(key)
                return key
            c.decoded_frames += 1
            self._track_counter(key, stamp, values)
            if self._newest_time is None or stamp > self._newest_time:
                self._newest_time = stamp
            fill = self._fill.get(key)
            if fill is not None and values is not None:  # values: decoded, no reason
                fill(self._live, values)
                self._stamps[key] = stamp
                self._rejected.discard(key)
        return key

    def _track_counter(self, key: int, stamp: float,
                       values: Mapping[str, float | int] | None) -> None:
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

    # -- the compiled intake's access (clutch_ros.canbus.intake: this class's twin) ------------

    @property
    def lock(self) -> threading.Lock:
        """The lock of the assembler's state.

        A caller holds it around :meth:`counter_state`, its own work and
        :meth:`apply_frames`, so they act as one step.
        """
        return self._lock

    def cycle_time(self, key: int) -> float | None:
        """Return the DBC cycle time [s] of frame ``key`` (None: not cyclic or unknown)."""
        return self._cycle.get(key)

    def counter_state(self, keys: Iterable[int]) -> tuple[list[tuple[float, int] | None],
                                                          float | None]:
        """Return the rolling counters of ``keys`` and the newest decoded frame's bus time.

        Per key its newest counter ``(bus time [s], value)`` or None; the bus time [s] or
        None before any frame. Call with :attr:`lock` held.
        """
        last = self._last_counter
        return [last.get(key) for key in keys], self._newest_time

    def apply_frames(self, counts: tuple[int, int, int, int, int],
                     unknown: Iterable[tuple[int, int]],
                     per_key: Iterable[tuple[int, int, tuple[float, int] | None]],
                     newest: float | None, fields: Iterable[tuple[str, int, float | int | bool]],
                     derive: tuple[bool, bool], filled: Iterable[tuple[int, float]]) -> None:
        """Apply what a run of clean rig frames did, as :meth:`feed_frame` would have.

        * ``counts``: additions to the :class:`FrameCounters` ``frames_total``,
          ``data_frames``, ``decoded_frames``, ``dropped_frames`` and ``counter_repeats``;
        * ``unknown``: ``(frame key, frames)`` of foreign frames in the order first seen
          (counted as :meth:`FrameCounters.count_unknown` does, not in ``counts``);
        * ``per_key``: ``(frame key, frames, newest rolling counter or None)``;
        * ``newest``: the newest decoded frame's bus time [s] (None: unchanged);
        * ``fields``: ``(RigSample field, element or -1, value)`` in the order written;
        * ``derive``: (slip_speed, has_measured_torque) to derive as the last frame's fill
          left them (``_filler``);
        * ``filled``: ``(frame key, bus time [s])`` of the frames whose values were written.

        Call with :attr:`lock` held.
        """
        c = self._counters
        total, data, decoded, dropped, repeats = counts
        c.frames_total += total
        c.data_frames += data
        c.decoded_frames += decoded
        c.dropped_frames += dropped
        c.counter_repeats += repeats
        for key, n in unknown:
            c.count_unknown(key, n)
        last = self._last_counter
        for key, n, counter in per_key:
            c.per_id[key] += n
            if counter is not None:
                last[key] = counter
        if newest is not None:
            self._newest_time = newest
        sample = self._live
        for name, element, value in fields:
            if element >= 0:
                array = getattr(sample, name)
                if not array:
                    array = [_NAN] * ARRAY_LEN[name]
                    setattr(sample, name, array)
                array[element] = value
            else:
                setattr(sample, name, value)
        if derive[0]:
            sample.slip_speed = sample.input_speed - sample.output_speed
        if derive[1]:
            sample.has_measured_torque = math.isfinite(sample.measured_torque)
        for key, stamp in filled:
            self._stamps[key] = stamp
            self._rejected.discard(key)

    @property
    def newest_time(self) -> float | None:
        """Bus timestamp [s] of the newest decoded frame, None before any."""
        with self._lock:
            return self._newest_time

    def snapshot(self, now: float | None = None) -> RigSample:
        """Return a copy of the live :class:`RigSample` with ages and ``stale_mask`` set.

        ``now`` [s] is the time in the bus time base the groups are aged at; when None the
        newest decoded frame's timestamp, the sample's own stamp (the can_bridge node, live
        and from a log: a group is stale when it fell behind the rest of the bus).
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
        received: dict[str | None, bool] = {}  # sibling None: no sibling
        for group in self.groups:
            keys = self._group_keys[group.name]
            seen = [stamps[k] for k in keys if k in stamps]
            received[group.name] = bool(seen)
            sample.ages[group.name] = max(0.0, now - min(seen)) if seen else math.inf
        for group in self.groups:
            keys = self._group_keys[group.name]
            if not keys:
                continue
            n_seen = sum(k in stamps for k in keys)
            sibling = self._sibling.get(group.name)
            if (
                (n_seen == 0 and (group.required or received.get(sibling, False)))
                or 0 < n_seen < len(keys)
                or (n_seen and sample.ages[group.name] > group.max_age)
                or any(k in rejected for k in keys)
            ):
                sample.stale_mask |= 1 << group.bit
                sample.stale.append(group.name)
        sample.stamp = max(stamps.values()) if stamps else None
        if sample.stale_mask & 1:  # pressure_torque stale: no valid measured torque
            sample.has_measured_torque = False
        return sample


def _filler(writes: tuple[Write, ...]) -> Callable[[RigSample, Mapping[str, float | int]],
                                                  None]:
    """Return the function that writes one frame's decoded values into a sample.

    Scalars and array elements get ``mult * value + offset``; ``has_measured_torque`` is the
    mapped flag (else: the torque is finite), ``pump_state`` an int (its frame's
    ``PumpSts_Flt*`` signals, when present, give ``pump_faults``), ``slip_speed`` is input minus
    output speed unless mapped.
    """
    special = SPECIAL_FIELDS
    scalars = tuple((w.field, w.signal, w.mult, w.offset) for w in writes
                    if w.index is None and w.field not in special)
    elements = tuple((w.field, w.index, w.signal, w.mult, w.offset, ARRAY_LEN[w.field])
                     for w in writes if w.index is not None)
    by_key = {w.key: w for w in writes}
    valid = by_key["has_measured_torque"].signal if "has_measured_torque" in by_key else None
    torque_only = valid is None and "measured_torque" in by_key
    state = by_key["pump_state"].signal if "pump_state" in by_key else None
    slip = "slip_speed" not in by_key and bool({"input_speed", "output_speed"} & set(by_key))

    def fill(sample: RigSample, v: Mapping[str, float | int]) -> None:
        for name, signal, mult, offset in scalars:
            setattr(sample, name, mult * v[signal] + offset)
        for name, index, signal, mult, offset, size in elements:
            values = getattr(sample, name)
            if not values:
                values = [_NAN] * size
                setattr(sample, name, values)
            values[index] = mult * v[signal] + offset
        if valid is not None:
            sample.has_measured_torque = bool(v[valid])
        elif torque_only:
            sample.has_measured_torque = math.isfinite(sample.measured_torque)
        if state is not None:
            sample.pump_state = int(v[state])
            sample.pump_faults = sum(1 << i for i, n in enumerate(PUMP_FAULTS) if v.get(n))
        if slip:
            sample.slip_speed = sample.input_speed - sample.output_speed

    return fill
