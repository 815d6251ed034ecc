"""The simulated rig on a CAN bus: rig frames out at their DBC cycle times, pump requests in.

:class:`FrameScheduler` says which frames are due at a simulation time (cycle times from the
DBC's ``GenMsgCycleTime``). :class:`PumpRequestMonitor` plays the pump ECU's request
supervision: it verifies each ``PumpRequest``'s CRC-8 checksum and that the rolling counter
advanced by exactly 1 (mod 16) since the previous frame, keeps the latest valid request with
its receive time, counts the bad ones, and yields the request the pump follows — 0 Pa when no
valid frame arrived within the timeout (the DBC's 100 ms) or, as the DBC demands of the pump,
while the last frame received was invalid. :class:`RigCanPort` ties both to a python-can bus.
:class:`~clutch_ros.rig.simulator.RigSimulator` runs plant, scenario and
port at 1 kHz.

The rig sim is every sender of the rig DBC except the bridge: the rig DAQ (RigFast, RigSpeed,
RigTemperatures, FlexiForce*), the pump ECU (PumpStatus), the vehicle (WheelSpeeds, when the
plant derives them) and the test host (TorqueRequest, when the scenario has a torque request).
Values are clamped into their DBC ranges before encoding, so a frame is always sent.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import can

from clutch_ros.canbus.batch import frame_message
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.errors import CanError, FrameDecodeError
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.rig.errors import RigConfigError, check_positive

__all__ = [
    "FrameScheduler",
    "PumpRequest",
    "PumpRequestMonitor",
    "PumpStatusState",
    "RigCanPort",
    "TX_FRAMES",
]

#: Frames the simulated rig sends, in sending order within a tick.
TX_FRAMES = ("RigFast", "RigSpeed", "PumpStatus", "FlexiForceFront", "FlexiForceRear",
             "WheelSpeeds", "TorqueRequest", "RigTemperatures")

_EPS = 1e-9  # [s] tolerance when comparing scheduled times


class PumpStatusState:
    """Values of ``PumpSts_State`` (DBC value table)."""

    OFF, READY, ACTIVE, DEGRADED, FAULT = 0, 1, 2, 3, 4


class FrameScheduler:
    """Cyclic transmit schedule: which frames are due at a given time.

    Frame ``name`` with period ``T`` [s] is due at ``start + k·T`` (k = 0, 1, ...); ``start``
    None means "the time of the first :meth:`due` call". Times are kept as integer cycle
    counts, so there is no drift over long runs. :meth:`due` returns each due frame once even
    when several of its slots passed (a late caller does not burst).
    """

    def __init__(self, periods: Mapping[str, float], start: float | None = None) -> None:
        self.periods = {name: check_positive(f"cycle time of {name}", period)
                        for name, period in periods.items()}
        self.reset(start)

    def reset(self, start: float | None = None) -> None:
        """Restart the schedule at ``start`` [s] (None: at the next call): all frames due."""
        self.start = None if start is None else float(start)
        self._cycle = dict.fromkeys(self.periods, 0)

    def next_due(self, name: str) -> float:
        """Return the next time [s] frame ``name`` is due (nan before the schedule started)."""
        if self.start is None:
            return math.nan
        return self.start + self._cycle[name] * self.periods[name]

    def due(self, now: float) -> list[str]:
        """Return the frames due at ``now`` [s] (in ``periods`` order) and advance them."""
        if self.start is None:
            self.start = float(now)
        out = []
        for name, period in self.periods.items():
            k = self._cycle[name]
            if self.start + k * period <= now + _EPS:
                out.append(name)
                # next slot strictly after now (skip missed slots instead of bursting)
                self._cycle[name] = max(k + 1, math.floor((now - self.start) / period
                                                          + _EPS) + 1)
        return out


@dataclass(frozen=True)
class PumpRequest:
    """A valid pump request: ``pressure`` [Pa], rolling ``counter``, ``receive_time`` [s]."""

    pressure: float
    counter: int
    receive_time: float


class PumpRequestMonitor:
    """E2E supervision of ``PumpRequest`` frames and the request the pump follows.

    Args:
        codec: decodes PumpRequest frames (checksum verified here)
        timeout: a valid request older than this falls back to 0 Pa [s] (DBC: 0.1 s)
        release_on_e2e_error: follow 0 Pa while the newest frame failed its checksum or
            counter check (the DBC's pump requirement); False keeps the last valid request
            until the timeout

    Counter rule: a frame's counter must be the previous frame's + 1 (mod 16). The previous
    counter is that of the last frame with a correct checksum, valid or not, so the check
    resynchronises one frame after a gap. The first frame, and the first after a timeout,
    is accepted with any counter.
    """

    def __init__(self, codec: PumpRequestCodec, timeout: float = 0.1,
                 release_on_e2e_error: bool = True) -> None:
        self.codec = codec
        self.timeout = check_positive("request timeout", timeout)
        self.release_on_e2e_error = bool(release_on_e2e_error)
        self.latest: PumpRequest | None = None
        self._last_counter: int | None = None
        self._last_frame_time = -math.inf
        self._e2e_error = False
        self.valid = 0
        self.bad_checksum = 0
        self.bad_counter = 0
        self.bad_length = 0
        self.checksum_fault = False
        self.counter_fault = False

    @property
    def invalid(self) -> int:
        """Number of rejected PumpRequest frames (checksum, counter or length)."""
        return self.bad_checksum + self.bad_counter + self.bad_length

    def feed(self, msg: can.Message, now: float) -> bool:
        """Check one PumpRequest frame received at ``now`` [s]; return True when valid."""
        try:
            pressure, counter, checksum_ok = self.codec.decode(msg)
        except (FrameDecodeError, CanError):
            self.bad_length += 1
            self._e2e_error = True
            return False
        if not checksum_ok:
            self.bad_checksum += 1
            self.checksum_fault = self._e2e_error = True
            return False
        previous = self._last_counter
        resync = previous is None or now - self._last_frame_time > self.timeout
        self._last_counter = counter
        self._last_frame_time = now
        if not resync and previous is not None and counter != (previous + 1) % 16:
            self.bad_counter += 1
            self.counter_fault = self._e2e_error = True
            return False
        self.valid += 1
        self._e2e_error = self.checksum_fault = self.counter_fault = False
        self.latest = PumpRequest(float(pressure), int(counter), float(now))
        return True

    def timed_out(self, now: float) -> bool:
        """Return True when a valid request was once received but none within ``timeout``."""
        return self.latest is not None and now - self.latest.receive_time > self.timeout

    def requested_pressure(self, now: float) -> float:
        """Return the pressure the pump follows at ``now`` [Pa] (0 when stale or faulted)."""
        if self.latest is None or self.timed_out(now):
            return 0.0
        if self._e2e_error and self.release_on_e2e_error:
            return 0.0
        return self.latest.pressure


def _clamped(db: RigDatabase, values: Mapping[str, float]) -> dict[str, float]:
    out = {}
    for name, value in values.items():
        sig = db.signal(name)
        value = float(value)
        if not math.isfinite(value):
            value = 0.0
        if sig.minimum is not None:
            value = max(value, sig.minimum)
        if sig.maximum is not None:
            value = min(value, sig.maximum)
        out[name] = value
    return out


class RigCanPort:
    """The rig's CAN interface on a python-can bus (see the module docstring).

    Args:
        bus: an open python-can bus (``virtual`` in tests, ``udp_multicast`` between
            processes, any interface on a real rig); not closed by the port
        database: the rig DBC (default: ``params/rig.dbc``)
        request_timeout: PumpRequest timeout [s] (default 0.1, the DBC's)
        release_on_e2e_error: see :class:`PumpRequestMonitor`
        frames: names of the frames to send (default :data:`TX_FRAMES`); WheelSpeeds and
            TorqueRequest are skipped while the signals carry none
        start_time: simulation time of the first slot [s] (None: the first send)

    """

    def __init__(self, bus: can.BusABC, database: RigDatabase | None = None,
                 request_timeout: float = 0.1, release_on_e2e_error: bool = True,
                 frames: Iterable[str] = TX_FRAMES, start_time: float | None = None) -> None:
        self.bus = bus
        self.db = database if database is not None else RigDatabase()
        self.codec = PumpRequestCodec(self.db)
        self.monitor = PumpRequestMonitor(self.codec, request_timeout, release_on_e2e_error)
        periods = {}
        for name in frames:
            spec = self.db.frame(name)
            if spec.cycle_time is None:
                raise RigConfigError(f"frame {name} has no cycle time in {self.db.path}")
            periods[name] = spec.cycle_time
        self.scheduler = FrameScheduler(periods, start_time)
        self._counters = dict.fromkeys(periods, 0)
        self._request_key = self.codec.spec.frame_id
        self.sent = 0
        self.send_errors = 0
        self.received = 0
        self.other_frames = 0

    # -- transmit ------------------------------------------------------------------------

    def pump_status_values(self, signals, now: float) -> dict[str, float]:
        """Return the SI values of ``PumpStatus`` for ``signals`` at ``now`` [s]."""
        mon = self.monitor
        timed_out = mon.timed_out(now)
        fault = timed_out or mon.checksum_fault or mon.counter_fault
        if fault:
            state = PumpStatusState.DEGRADED
        elif mon.requested_pressure(now) > 0.0:
            state = PumpStatusState.ACTIVE
        else:
            state = PumpStatusState.READY
        return {
            "PumpSts_State": state,
            "PumpSts_ActualPressure": signals.pump_pressure,
            "PumpSts_Current": signals.pump_current,
            "PumpSts_FltOverCurrent": 0, "PumpSts_FltOverTemp": 0,
            "PumpSts_FltUnderVoltage": 0, "PumpSts_FltSensor": 0,
            "PumpSts_FltReqTimeout": int(timed_out),
            "PumpSts_FltReqChecksum": int(mon.checksum_fault),
            "PumpSts_FltReqCounter": int(mon.counter_fault),
        }

    def frame_values(self, name: str, signals, now: float) -> dict[str, float] | None:
        """Return the SI signal values of frame ``name`` for ``signals``, None to skip it."""
        s = signals
        if name == "RigFast":
            return {"ActuatingPressure": s.actuating_pressure,
                    "MeasuredTorque": s.measured_torque if s.has_measured_torque else 0.0,
                    "MeasuredTorqueValid": int(bool(s.has_measured_torque))}
        if name == "RigSpeed":
            return {"InputShaftSpeed": s.input_speed, "OutputShaftSpeed": s.output_speed}
        if name == "RigTemperatures":
            return {"LamellaTemperature": s.lamella_temperature,
                    "OilTemperature": s.oil_temperature}
        if name in ("FlexiForceFront", "FlexiForceRear"):
            if len(s.ff_voltages) != 8:
                return None
            side, base = ("Front", 0) if name == "FlexiForceFront" else ("Rear", 4)
            return {f"FF_{side}{i + 1}": s.ff_voltages[base + i] for i in range(4)}
        if name == "WheelSpeeds":
            if len(s.wheel_speeds) != 4:
                return None
            return dict(zip(("WheelSpeedFL", "WheelSpeedFR", "WheelSpeedRL", "WheelSpeedRR"),
                            s.wheel_speeds))
        if name == "TorqueRequest":
            if not math.isfinite(s.torque_request):
                return None
            return {"TorqueRequest": s.torque_request}
        if name == "PumpStatus":
            return self.pump_status_values(s, now)
        raise RigConfigError(f"the rig does not send frame {name!r}")

    def frames_due(self, now: float, signals, timestamp: float | None = None
                   ) -> list[can.Message]:
        """Return the frames due at ``now`` [s], encoded from ``signals`` (a RigSignals).

        ``timestamp`` [s] is written into the messages (default: ``now``).
        """
        stamp = now if timestamp is None else timestamp
        out = []
        for name in self.scheduler.due(now):
            values = self.frame_values(name, signals, now)
            if values is None:
                continue
            spec = self.db.frame(name)
            counter = None
            if spec.counter_signal is not None:
                counter = self._counters[name]
                self._counters[name] = (counter + 1) % 16
            out.append(self.db.make_message(name, _clamped(self.db, values), counter=counter,
                                            timestamp=stamp, strict=False))  # clamped here
        return out

    def send_due(self, now: float, signals, timestamp: float | None = None) -> int:
        """Send the frames due at ``now`` [s]; return how many were sent.

        Send failures (full buffers, a link down) are counted in ``send_errors``, never raised.
        """
        count = 0
        for msg in self.frames_due(now, signals, timestamp):
            try:
                self.bus.send(msg, timeout=0.0)
            except (can.CanError, OSError):
                self.send_errors += 1
                continue
            count += 1
        self.sent += count
        return count

    # -- receive -------------------------------------------------------------------------

    def poll(self, now: float, max_frames: int = 1000) -> int:
        """Receive pending frames without blocking; return the number of valid pump requests.

        ``now`` [s] is the receive time recorded for the requests (the simulation clock, so a
        non-real-time run stays deterministic). Other frames are counted and ignored.
        """
        recv_batch = getattr(self.bus, "recv_batch", None)
        if recv_batch is not None:  # a ReconnectingBus: its checked reader (no can.Message each)
            return self._poll_batch(recv_batch, now, max_frames)
        valid = 0
        for _ in range(max_frames):
            try:
                msg = self.bus.recv(timeout=0.0)
            except (can.CanError, OSError):
                break
            if msg is None:
                break
            self.received += 1
            if (msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id
                    or msg.arbitration_id != self._request_key):
                self.other_frames += 1
                continue
            valid += self.monitor.feed(msg, now)
        return valid

    def _poll_batch(self, recv_batch, now: float, max_frames: int) -> int:
        """:meth:`poll` through :meth:`ReconnectingBus.recv_batch`.

        On udp_multicast that reader checks each datagram before python-can sees it: a
        datagram whose ``data`` is a huge integer made python-can's own ``recv`` allocate
        that many bytes (2**33: the simulated rig was killed for its memory); the reader
        counts it as malformed (``malformed_frames``) instead. Other interfaces: the bus's
        ``recv``, as before.
        """
        try:
            frames = recv_batch(0.0, max_frames)
        except (can.CanError, OSError):
            return 0
        valid, key = 0, self._request_key
        for frame in frames:
            _stamp, ident, ext, remote, error = frame[:5]
            self.received += 1
            if error or remote or ext or ident != key:
                self.other_frames += 1
                continue
            valid += self.monitor.feed(frame_message(frame), now)
        return valid

    @property
    def latest_request(self) -> PumpRequest | None:
        """The latest valid pump request (pressure [Pa], counter, receive time [s])."""
        return self.monitor.latest

    def requested_pressure(self, now: float) -> float:
        """Return the pressure the pump follows at ``now`` [Pa] (see the monitor)."""
        return self.monitor.requested_pressure(now)

