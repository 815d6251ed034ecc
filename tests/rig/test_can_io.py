"""RigCanPort and RigSimulator over python-can's virtual bus, decoded with the RigDatabase."""

import threading
import time
import uuid

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.rig.can_io import FrameScheduler, RigCanPort
from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.plant import RigPlant
from clutch_ros.rig.scenario import closed_loop_run, table3_run
from clutch_ros.rig.simulator import RigSimulator

BAR = 1e5


@pytest.fixture(scope="module")
def db():
    return RigDatabase()


@pytest.fixture
def buses():
    """(rig side, bridge side) of a fresh virtual channel; the rig keeps its timestamps."""
    channel = f"rig-test-{uuid.uuid4().hex}"
    rig = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    bridge = can.Bus(interface="virtual", channel=channel)
    yield rig, bridge
    rig.shutdown()
    bridge.shutdown()


def drain(bus):
    out = []
    while (msg := bus.recv(timeout=0.0)) is not None:
        out.append(msg)
    return out


def test_scheduler_follows_cycle_times_without_bursts():
    sched = FrameScheduler({"fast": 0.001, "mid": 0.01, "slow": 0.1}, start=0.0)
    counts = {"fast": 0, "mid": 0, "slow": 0}
    for k in range(1000):
        for name in sched.due(k * 0.001):
            counts[name] += 1
    assert counts == {"fast": 1000, "mid": 100, "slow": 10}
    assert sched.next_due("slow") == pytest.approx(1.0)
    assert sched.due(1.55) == ["fast", "mid", "slow"]  # late: once each, no burst
    assert sched.due(1.5505) == []
    assert sched.next_due("mid") == pytest.approx(1.56)
    lazy = FrameScheduler({"mid": 0.01})
    assert np.isnan(lazy.next_due("mid"))
    assert lazy.due(0.003) == ["mid"] and lazy.next_due("mid") == pytest.approx(0.013)
    with pytest.raises(RigConfigError):
        FrameScheduler({"x": 0.0})


def test_frames_decode_to_plant_signals_within_dbc_resolution(db, buses):
    rig_bus, bridge = buses
    port = RigCanPort(rig_bus, db)
    by_time = {}
    sim = RigSimulator(RigPlant(seed=4), table3_run(1, 30.0), port,
                       on_step=lambda s: by_time.__setitem__(round(s.time * 1e3), s))
    stats = sim.run(1.5, realtime=False)  # into the pressure step (kick) at 1.0 s
    assert stats.steps == 1500 and stats.overruns == 0
    frames = drain(bridge)
    assert stats.frames_sent == len(frames) == port.sent
    names = [db.lookup(m.arbitration_id).name for m in frames]
    # DBC cycle times over 1.5 s: 1 ms, 10 ms, 100 ms; no torque request in this scenario
    assert names.count("RigFast") == names.count("RigSpeed") == 1500
    for name in ("PumpStatus", "FlexiForceFront", "FlexiForceRear", "WheelSpeeds"):
        assert names.count(name) == 150
    assert names.count("RigTemperatures") == 15 and "TorqueRequest" not in names
    half = {sig.name: sig.resolution / 2 + 1e-9 * max(1.0, abs(sig.maximum or 1.0))
            for spec in db.frames for sig in spec.signals}
    fast_counters = []
    for msg in frames:
        spec, values = db.decode_message(msg)
        s = by_time[round(msg.timestamp * 1e3)]
        expected = {
            "ActuatingPressure": s.actuating_pressure, "MeasuredTorque": s.measured_torque,
            "MeasuredTorqueValid": 1, "InputShaftSpeed": s.input_speed,
            "OutputShaftSpeed": s.output_speed, "LamellaTemperature": s.lamella_temperature,
            "OilTemperature": s.oil_temperature, "PumpSts_Current": s.pump_current,
            "PumpSts_ActualPressure": s.pump_pressure,
            **{f"FF_Front{i + 1}": s.ff_voltages[i] for i in range(4)},
            **{f"FF_Rear{i + 1}": s.ff_voltages[4 + i] for i in range(4)},
            **dict(zip(("WheelSpeedFL", "WheelSpeedFR", "WheelSpeedRL", "WheelSpeedRR"),
                       s.wheel_speeds)),
        }
        for name, value in values.items():
            if name in expected:
                assert abs(value - expected[name]) <= half[name], (spec.name, name)
        if spec.name == "RigFast":
            fast_counters.append(values["RigFast_Counter"])
        if spec.name == "PumpStatus":
            assert values["PumpSts_State"] == 1  # ready: no request on the bus
    assert np.all(np.diff(fast_counters) % 16 == 1)


def send_requests(bus, codec, pressures, counters, corrupt=()):
    for i, (p, c) in enumerate(zip(pressures, counters)):
        msg = codec.encode(p, c)
        if i in corrupt:
            msg.data[0] ^= 0x5A
        bus.send(msg)


def test_pump_requests_verified_counted_and_timed_out(db, buses):
    rig_bus, bridge = buses
    port = RigCanPort(rig_bus, db)
    codec = PumpRequestCodec(db)
    send_requests(bridge, codec, [10 * BAR, 12 * BAR, 14 * BAR], [14, 15, 0])
    assert port.poll(0.0) == 3  # counter wraps 15 -> 0
    assert port.latest_request.pressure == pytest.approx(14 * BAR)
    assert port.requested_pressure(0.05) == pytest.approx(14 * BAR)
    # bad checksum: rejected, counted, the pump releases until the next valid frame
    send_requests(bridge, codec, [30 * BAR], [1], corrupt={0})
    assert port.poll(0.01) == 0 and port.monitor.bad_checksum == 1
    assert port.requested_pressure(0.01) == 0.0
    assert port.latest_request.pressure == pytest.approx(14 * BAR)
    send_requests(bridge, codec, [16 * BAR], [1])  # the corrupt frame did not consume 1
    assert port.poll(0.02) == 1 and port.requested_pressure(0.02) == pytest.approx(16 * BAR)
    # repeated counter, then a jump: both rejected; the stream resynchronises after them
    send_requests(bridge, codec, [20 * BAR, 21 * BAR, 22 * BAR], [1, 5, 6])
    assert port.poll(0.03) == 1
    assert port.monitor.bad_counter == 2 and port.monitor.invalid == 3
    assert port.latest_request.pressure == pytest.approx(22 * BAR)
    assert port.latest_request.counter == 6 and port.latest_request.receive_time == 0.03
    # non-request frames are ignored, a wrong length is rejected
    bridge.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
    bridge.send(can.Message(arbitration_id=0x80, data=bytes(4), is_extended_id=False))
    assert port.poll(0.04) == 0 and port.other_frames == 1 and port.monitor.bad_length == 1
    send_requests(bridge, codec, [22 * BAR], [7])
    port.poll(0.05)
    # silence for more than 100 ms: 0 Pa, and PumpStatus reports the timeout
    assert port.requested_pressure(0.15) == pytest.approx(22 * BAR)
    assert port.requested_pressure(0.151) == 0.0
    status = port.pump_status_values(RigPlant().step(1e-3, 0.0, 0.0), 0.151)
    assert status["PumpSts_FltReqTimeout"] == 1 and status["PumpSts_State"] == 3
    # after a timeout any counter restarts the stream
    send_requests(bridge, codec, [5 * BAR], [11])
    assert port.poll(0.3) == 1 and port.requested_pressure(0.3) == pytest.approx(5 * BAR)


def test_closed_loop_simulator_follows_bus_requests(db, buses):
    rig_bus, bridge = buses
    port = RigCanPort(rig_bus, db)
    codec = PumpRequestCodec(db)
    scenario = closed_loop_run((10.0, 30.0), segment=1.0, lead=0.2, rest=0.3,
                               torque_steps=[(0.0, 500.0)])
    sim = RigSimulator(RigPlant(seed=7), scenario, port)
    received = []
    for k in range(150):  # the "bridge" sends 25 bar every 10 ms for 1.5 s
        bridge.send(codec.encode(25 * BAR, k % 16))
        sim.run(0.01, realtime=False)
        received += drain(bridge)
    assert sim.time == pytest.approx(1.5)
    assert port.monitor.valid == 150 and port.monitor.invalid == 0
    assert sim.signals.true_actuating_pressure == pytest.approx(25 * BAR, rel=2e-3)
    # 30 rpm since 1.2 s: six motor time constants (e^-6 = 0.25 %)
    assert sim.signals.true_slip_speed == pytest.approx(30 * 2 * np.pi / 60, rel=5e-3)
    decoded = [db.decode_message(m) for m in received]
    fast = [v for spec, v in decoded if spec.name == "RigFast"]
    assert fast[-1]["ActuatingPressure"] == pytest.approx(25 * BAR, abs=0.2 * BAR)
    assert fast[-1]["MeasuredTorque"] > 500.0
    status = [v for spec, v in decoded if spec.name == "PumpStatus"]
    assert status[-1]["PumpSts_State"] == 2  # active
    torque = [v for spec, v in decoded if spec.name == "TorqueRequest"]
    assert torque and torque[-1]["TorqueRequest"] == pytest.approx(500.0)
    # the requests stop (the last one was received at 1.49 s): the pump follows it until
    # 100 ms after its arrival, then releases towards 0 bar
    sim.run(0.09, realtime=False)
    assert sim.signals.requested_pressure == pytest.approx(25 * BAR)
    sim.run(0.2, realtime=False)
    assert sim.signals.requested_pressure == 0.0
    assert sim.signals.true_actuating_pressure < 5 * BAR
    status = [db.decode_message(m)[1] for m in drain(bridge)
              if db.lookup(m.arbitration_id).name == "PumpStatus"]
    assert status[-1]["PumpSts_FltReqTimeout"] == 1


def test_realtime_run_is_paced_and_stoppable(db, buses):
    rig_bus, _ = buses
    sim = RigSimulator(RigPlant(), table3_run(1, 10.0), RigCanPort(rig_bus, db))
    stats = sim.run(0.1, realtime=True)
    assert stats.steps == 100 and stats.wall_time >= 0.095
    timer = threading.Timer(0.05, sim.stop)
    timer.start()
    stats = sim.run(float("inf"), realtime=True)
    timer.join()
    assert stats.stopped and stats.steps >= 1
    # a stalled clock: the loop drops the backlog instead of bursting
    now = [0.0]

    def clock():
        now[0] += 0.0004
        return now[0]

    def sleep(seconds):
        now[0] += seconds

    stats = sim.run(0.05, realtime=True, clock=clock, sleep=sleep)
    assert stats.steps == 50 and stats.overruns == 0
    assert stats.wall_time == pytest.approx(0.05, abs=0.002)
    ticks = []

    def freeze_once(signals):
        ticks.append(signals)
        if len(ticks) == 3:
            now[0] += 5.0  # the machine froze for 5 s during the third tick

    sim.on_step = freeze_once
    stats = sim.run(0.01, realtime=True, clock=clock, sleep=sleep)
    assert stats.overruns == 1 and stats.steps == 10
    assert stats.wall_time == pytest.approx(5.01, abs=0.002)  # no burst to catch up
    # the live counters (the node's /diagnostics) hold the dropped real time: the 5 s freeze
    # less the 1 ms tick it ended in; the 0.4 ms clock reads make the rest (atol 2 ms)
    assert sim.overruns == 1
    assert sim.lost_time == pytest.approx(5.0, abs=0.002)
    with pytest.raises(RigConfigError):
        RigSimulator(RigPlant(), closed_loop_run())


_ANY = st.floats(allow_nan=True, allow_infinity=True, width=64) | st.sampled_from(
    [0.0, -1e12, 1e12, 65.535e5, 65.536e5])


@settings(max_examples=200, deadline=None, derandomize=True)
@given(pressure=_ANY, torque=_ANY, speed=_ANY, temp=_ANY, volt=_ANY, current=_ANY)
def test_rig_frames_skip_the_range_check_only_for_values_already_clamped(
        pressure, torque, speed, temp, volt, current):
    """The rig's frames (cantools strict=False) equal strict encodes of the clamped values.

    Whatever the plant hands the port: NaN, inf, far out of range.
    """
    import dataclasses

    from clutch_ros.rig.can_io import _clamped

    db = RigDatabase()
    port = RigCanPort(None, db)  # frames_due never touches the bus
    plant = RigPlant(seed=1)
    base = plant.step(1e-3, 20e5, 3.0, torque_request=100.0)
    signals = dataclasses.replace(
        base, actuating_pressure=pressure, measured_torque=torque, input_speed=speed,
        output_speed=speed, lamella_temperature=temp, oil_temperature=temp,
        ff_voltages=np.full(8, volt), wheel_speeds=np.full(4, speed), pump_current=current,
        pump_pressure=pressure, torque_request=torque)
    frames = port.frames_due(0.1, signals)
    assert {db.lookup(f.arbitration_id).name for f in frames} >= {"RigFast", "RigSpeed"}
    for frame in frames:
        spec = db.lookup(frame.arbitration_id)
        counter = (db.decode(frame.arbitration_id, frame.data)[spec.counter_signal]
                   if spec.counter_signal is not None else None)
        values = _clamped(db, port.frame_values(spec.name, signals, 0.1))
        assert frame.data == bytearray(db.encode(spec.name, values, counter=counter,
                                                 strict=True)), spec.name


def test_pump_requests_over_udp_survive_a_gigabyte_payload_count(db):
    """On a ReconnectingBus over udp_multicast the port reads through ``recv_batch``.

    A datagram whose ``data`` is an integer (python-can: that many zero bytes, allocated
    before its frame check; 2**33 killed the simulated rig for its memory) is counted as
    malformed; the valid requests around it are verified as on any bus, and the rig's own
    frames (echoes) never reach the monitor.
    """
    import resource

    import msgpack

    from clutch_ros.canbus.bus import BusConfig, ReconnectingBus
    from tests.canbus.recorder import DatagramSender, _frame_dict, private_group

    group, udp_port = private_group()
    config = BusConfig(interface="udp_multicast", channel=group, extra={"port": udp_port})
    codec = PumpRequestCodec(db)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # [KiB]
    with ReconnectingBus(config) as rig_bus, ReconnectingBus(config) as bridge, \
            DatagramSender(group, udp_port) as junk:
        port = RigCanPort(rig_bus, db)
        port.send_due(0.0, RigPlant().step(1e-3, 0.0, 0.0))  # own frames: echoes to skip
        send_requests(bridge, codec, [10 * BAR], [3])
        junk.send(msgpack.packb(_frame_dict(arbitration_id=0x80, data=2**33, dlc=8),
                                use_bin_type=True))
        send_requests(bridge, codec, [12 * BAR, 30 * BAR], [4, 6])  # 6: a counter jump
        valid, deadline = 0, time.monotonic() + 10.0
        while port.received < 3 and time.monotonic() < deadline:  # (delivery is async)
            valid += port.poll(0.0)
            time.sleep(0.005)
        assert (port.received, valid, port.other_frames) == (3, 2, 0)
        assert port.monitor.bad_counter == 1
        assert port.latest_request.pressure == pytest.approx(12 * BAR)
        assert rig_bus.status().malformed_by_reason == {"invalid_frame": 1}
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown < 200_000, f"{grown} KiB more"  # python-can's recv alone: 8 GiB
