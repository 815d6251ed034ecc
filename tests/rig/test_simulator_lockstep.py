"""RigSimulator in lock-step, over python-can's virtual bus: a partner paces the run.

The partner stands in for the chain: at each sync tick it is told the time before the frames
go out, and after (it reads the frames, as the bridge does, and answers them with a
PumpRequest, as controller and bridge do). Frames go out only at sync ticks, once each; the
requests sent during the waits act from the next step on, so a run is the same however long
the partner takes.
"""

import time
import uuid

import can
import pytest

from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.rig.can_io import RigCanPort
from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.plant import RigPlant
from clutch_ros.rig.scenario import closed_loop_run
from clutch_ros.rig.simulator import RigSimulator

BAR = 1e5
DB = RigDatabase()


class Partner:
    """A lock-step partner: records each sync tick's frames, answers them with a PumpRequest."""

    def __init__(self, bus: can.BusABC, every: int, pressure: float, delay: float = 0.0):
        self.every, self.bus, self.pressure, self.delay = every, bus, pressure, delay
        self.codec = PumpRequestCodec(DB)
        self.calls: list[tuple[str, float]] = []
        self.frames: list[tuple[float, list[str]]] = []
        self._counter = 0

    def before_frames(self, t: float) -> None:
        self.calls.append(("before", t))

    def after_frames(self, t: float) -> None:
        self.calls.append(("after", t))
        names = []
        while (msg := self.bus.recv(timeout=0.0)) is not None:
            names.append(DB.lookup(msg.arbitration_id).name)
        self.frames.append((t, names))
        time.sleep(self.delay)  # a slow chain: the simulation waits, its time does not move
        self.bus.send(self.codec.encode(self.pressure, self._counter))
        self._counter = (self._counter + 1) % 16


def _run(delay: float, steps: float = 0.3):
    channel = f"lockstep-{uuid.uuid4().hex}"
    rig_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    bridge = can.Bus(interface="virtual", channel=channel)
    try:
        partner = Partner(bridge, 10, 20 * BAR, delay)
        scenario = closed_loop_run((10.0,), segment=1.0, lead=0.0, rest=0.0)
        sim = RigSimulator(RigPlant(seed=3), scenario, RigCanPort(rig_bus, DB),
                           lockstep=partner)
        sim.run(steps, realtime=False)
        return sim, partner
    finally:
        rig_bus.shutdown()
        bridge.shutdown()


def test_frames_only_at_sync_ticks_with_the_partner_called_around_them():
    sim, partner = _run(0.0)
    ticks = [round(0.01 * k, 6) for k in range(1, 31)]
    assert [round(t, 6) for kind, t in partner.calls if kind == "before"] == ticks
    assert [kind for kind, _ in partner.calls] == ["before", "after"] * 30
    for _, names in partner.frames:  # one of each due frame per sync tick, nothing between
        assert names.count("RigFast") == 1 and names.count("RigSpeed") == 1
        assert names.count("PumpStatus") == 1
    temperatures = [t for t, names in partner.frames if "RigTemperatures" in names]
    assert [round(t, 6) for t in temperatures] == [0.01, 0.11, 0.21]  # its 100 ms cycle
    # the requests answered at each tick are followed (received at the next step, in order;
    # the last one's step is not run)
    assert sim.port.monitor.valid == 29 and sim.port.monitor.invalid == 0
    assert sim.signals.requested_pressure == pytest.approx(20 * BAR, abs=0.1 * BAR)


def test_a_slow_partner_changes_nothing_but_the_wall_time():
    fast, _ = _run(0.0)
    slow, _ = _run(0.003)  # 3 ms of wall time per 10 ms tick: the rig waits
    assert slow.time == fast.time and slow.steps == fast.steps
    assert slow.signals.true_actuating_pressure == fast.signals.true_actuating_pressure
    assert slow.signals.measured_torque == fast.signals.measured_torque


@pytest.mark.parametrize("every", [0, -1, 1.5, True])
def test_a_bad_sync_period_is_refused(every):
    partner = Partner(None, 10, 0.0)
    partner.every = every
    with pytest.raises(RigConfigError, match="lock-step period"):
        RigSimulator(RigPlant(), closed_loop_run((10.0,)), None,
                     pressure_source=lambda t, s: 0.0, lockstep=partner)
