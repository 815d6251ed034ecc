"""RigStateAssembler: frames from a real python-can bus into RigSamples, ages, counters."""

import math
import threading
import time

import can
import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.errors import ConfigError

PUMP_OK = {
    "PumpSts_State": 2, "PumpSts_ActualPressure": 20.5e5, "PumpSts_Current": 7.25,
    "PumpSts_FltOverCurrent": 0, "PumpSts_FltOverTemp": 1, "PumpSts_FltUnderVoltage": 0,
    "PumpSts_FltSensor": 1, "PumpSts_FltReqTimeout": 0, "PumpSts_FltReqChecksum": 0,
    "PumpSts_FltReqCounter": 0,
}


def rig_frames(db, t=0.0, counter=0, valid=1):
    """One frame of every rig message with known values (SI), timestamp ``t`` [s]."""
    mk = db.make_message
    return [
        mk("RigFast", {"ActuatingPressure": 20e5, "MeasuredTorque": 456.7,
                       "MeasuredTorqueValid": valid}, counter=counter, timestamp=t),
        mk("RigSpeed", {"InputShaftSpeed": 5.236, "OutputShaftSpeed": -0.5},
           counter=counter, timestamp=t),
        mk("RigTemperatures", {"LamellaTemperature": 85.25, "OilTemperature": 40.5},
           timestamp=t),
        mk("PumpStatus", PUMP_OK, counter=counter, timestamp=t),
        mk("FlexiForceFront", {f"FF_Front{i}": 0.5 * i for i in range(1, 5)}, timestamp=t),
        mk("FlexiForceRear", {f"FF_Rear{i}": 0.1 * i for i in range(1, 5)}, timestamp=t),
        mk("WheelSpeeds", {"WheelSpeedFL": 10.0, "WheelSpeedFR": 10.5, "WheelSpeedRL": -3.0,
                           "WheelSpeedRR": 0.0}, timestamp=t),
        mk("TorqueRequest", {"TorqueRequest": 300.0}, timestamp=t),
    ]


def assert_rig_values(sample):
    assert sample.actuating_pressure == pytest.approx(20e5)
    assert sample.measured_torque == pytest.approx(456.7)
    assert sample.has_measured_torque
    assert sample.input_speed == pytest.approx(5.236, abs=1e-4)
    assert sample.output_speed == pytest.approx(-0.5, abs=1e-4)
    assert sample.slip_speed == pytest.approx(5.736, abs=2e-4)
    assert sample.lamella_temperature == pytest.approx(85.25)
    assert sample.oil_temperature == pytest.approx(40.5)
    assert sample.pump_current == pytest.approx(7.25)
    assert sample.pump_pressure == pytest.approx(20.5e5)
    assert sample.pump_state == 2
    assert sample.pump_faults == 0b1010
    assert sample.ff_voltages == pytest.approx([0.5, 1.0, 1.5, 2.0, 0.1, 0.2, 0.3, 0.4])
    assert sample.wheel_speeds == pytest.approx([10.0, 10.5, -3.0, 0.0], abs=0.006)
    assert sample.torque_request == pytest.approx(300.0)


def wait_for(predicate, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.002)


def test_frames_over_virtual_bus_with_notifier(db, channel):
    assembler = RigStateAssembler(db)
    seen = can.BufferedReader()
    with can.Bus(interface="virtual", channel=channel) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        notifier = can.Notifier(rx, [assembler, seen], timeout=0.05)
        try:
            for msg in rig_frames(db):
                tx.send(msg)
            wait_for(lambda: assembler.counters().decoded_frames == 8)
        finally:
            notifier.stop()
    stamps = []
    while (msg := seen.get_message(0.0)) is not None:
        stamps.append(msg.timestamp)
    sample = assembler.snapshot()  # aged against the newest frame: all fresh
    assert_rig_values(sample)
    assert sample.stale_mask == 0 and sample.stale == []
    assert assembler.snapshot(time.time() + 1.0).stale_mask == 0xFF
    assert sample.stamp == max(stamps)  # the virtual bus stamps frames on send
    counters = assembler.counters()
    assert counters.frames_total == counters.data_frames == 8
    assert counters.unknown_frames == counters.decode_errors == counters.dropped_frames == 0


def test_nothing_received_yet(db):
    sample = RigStateAssembler(db).snapshot(100.0)
    assert sample.stamp is None
    assert math.isnan(sample.actuating_pressure) and math.isnan(sample.slip_speed)
    assert math.isnan(sample.pump_current) and not sample.has_measured_torque
    assert sample.torque_request == 0.0
    assert sample.ff_voltages == [] and sample.wheel_speeds == []
    # required groups are stale until received; optional ones are not
    assert sample.stale_mask == 0b1111
    assert sample.stale == ["pressure_torque", "shaft_speeds", "temperatures", "pump_status"]
    assert sample.ages["wheel_speeds"] == math.inf


def test_stale_detection_with_injected_time(db):
    assembler = RigStateAssembler(db)
    for msg in rig_frames(db, t=10.0):
        assembler.feed(msg)
    assert assembler.snapshot(10.009).stale_mask == 0
    sample = assembler.snapshot(10.011)  # 1 ms frames: 10 ms max age
    assert sample.stale == ["pressure_torque", "shaft_speeds"]
    assert sample.stale_mask == 0b11
    assert not sample.has_measured_torque  # a stale measurement is no measurement
    assert sample.ages["pressure_torque"] == pytest.approx(0.011)
    assert sample.stamp == 10.0
    sample = assembler.snapshot(10.06)  # 10 ms frames: 50 ms
    assert sample.stale_mask == 0b11111011
    sample = assembler.snapshot(10.6)  # 100 ms frames: 500 ms
    assert sample.stale_mask == 0xFF
    assert len(sample.stale) == 8
    # values are kept while stale
    assert sample.actuating_pressure == pytest.approx(20e5)
    # fresh fast frames clear only their bits
    for msg in rig_frames(db, t=10.6, counter=1)[:2]:
        assembler.feed(msg)
    assert assembler.snapshot(10.6).stale_mask == 0xFC
    # None: age against the newest frame (log replay)
    assert assembler.snapshot().stamp == 10.6


def test_configurable_ages_and_required_groups(db):
    assembler = RigStateAssembler(
        db, max_ages={"pressure_torque": 0.5}, required=["pressure_torque", "wheel_speeds"]
    )
    sample = assembler.snapshot(0.0)
    assert sample.stale == ["pressure_torque", "wheel_speeds"]
    for msg in rig_frames(db, t=1.0)[:2]:
        assembler.feed(msg)
    assert assembler.snapshot(1.4).stale == ["shaft_speeds", "wheel_speeds"]
    with pytest.raises(ConfigError):
        RigStateAssembler(db, max_ages={"nope": 1.0})
    with pytest.raises(ConfigError):
        RigStateAssembler(db, max_ages={"temperatures": 0.0})
    with pytest.raises(ConfigError):
        RigStateAssembler(db, required=["bogus"])


def test_torque_validity_and_partial_flexiforce(db):
    assembler = RigStateAssembler(db)
    frames = rig_frames(db, t=1.0, valid=0)
    assembler.feed(frames[0])
    assembler.feed(frames[4])  # front FlexiForce only
    sample = assembler.snapshot(1.0)
    assert not sample.has_measured_torque
    assert sample.measured_torque == pytest.approx(456.7)
    assert sample.ff_voltages[:4] == pytest.approx([0.5, 1.0, 1.5, 2.0])
    assert all(math.isnan(v) for v in sample.ff_voltages[4:])


def test_dropped_frames_from_rolling_counter(db):
    assembler = RigStateAssembler(db)
    t = 0.0
    for counter in (14, 15, 0, 3, 4, 4, 5):  # 2 lost (1, 2), one repeat
        t += 0.001
        assembler.feed(rig_frames(db, t=t, counter=counter)[0])
    counters = assembler.counters()
    assert counters.dropped_frames == 2
    assert counters.counter_repeats == 1
    # after a silence longer than 16 cycles the counter cannot tell: not counted
    assembler.feed(rig_frames(db, t=t + 1.0, counter=11)[0])
    assert assembler.counters().dropped_frames == 2


def test_rates_per_id(db):
    assembler = RigStateAssembler(db)
    assert assembler.rates(0.0) == (0.0, {})
    for i in range(10):
        assembler.feed(rig_frames(db, t=i * 0.001, counter=i % 16)[0])
    total, per_id = assembler.rates(2.0)
    assert total == pytest.approx(5.0)
    assert per_id == {0x100: pytest.approx(5.0)}
    assert assembler.rates(3.0) == (0.0, {})


def test_concurrent_snapshots_while_notifier_feeds(db, channel):
    assembler = RigStateAssembler(db)
    n = 3000
    errors = []
    stop = threading.Event()

    def reader():
        try:
            while not stop.is_set():
                sample = assembler.snapshot(time.time())
                if not math.isnan(sample.input_speed):
                    assert sample.slip_speed == pytest.approx(
                        sample.input_speed - sample.output_speed)
        except Exception as err:  # reported below
            errors.append(err)

    thread = threading.Thread(target=reader)
    with can.Bus(interface="virtual", channel=channel) as tx, \
            can.Bus(interface="virtual", channel=channel) as rx:
        notifier = can.Notifier(rx, [assembler], timeout=0.05)
        thread.start()
        try:
            for i in range(n):
                tx.send(rig_frames(db, counter=(i // 2) % 16)[i % 2])
            wait_for(lambda: assembler.counters().frames_total == n)
        finally:
            stop.set()
            thread.join()
            notifier.stop()
    assert errors == []
    counters = assembler.counters()
    assert counters.decoded_frames == n and counters.dropped_frames == 0


def test_socketcan_error_classes_and_listener_errors(db):
    overflow = can.Message(arbitration_id=0x04, is_error_frame=True,
                           data=b"\x00\x01" + bytes(6))
    bus_off = can.Message(arbitration_id=0x40, is_error_frame=True, data=bytes(8))
    plain = RigStateAssembler(db)
    socketcan = RigStateAssembler(db, socketcan_error_frames=True)
    for assembler in (plain, socketcan):
        for msg in (overflow, bus_off, bus_off):
            assembler.feed(msg)
        assembler.on_error(RuntimeError("driver hiccup"))
    assert plain.counters().error_frames == socketcan.counters().error_frames == 3
    assert (plain.counters().bus_off_frames, plain.counters().controller_overflows) == (0, 0)
    assert (socketcan.counters().bus_off_frames,
            socketcan.counters().controller_overflows) == (2, 1)
    assert plain.counters().listener_errors == 1


def test_publish_pacer_paces_bus_time_and_a_clock_going_back_earns_nothing():
    """The bridge passes the frames' bus times: a backlog read late is paced as it was sent."""
    from clutch_ros.canbus.counters import PublishPacer

    speed = 0x101
    pacer = PublishPacer(100.0, speed, frozenset({speed}))
    # 300 trigger frames sent every 10 ms, read in one burst: each one publishes
    assert all(pacer.on_frame(speed, 100.0 + 0.01 * k) for k in range(300))
    # a new log starts at bus time 5 s: the step back neither earns nor costs tokens
    pacer = PublishPacer(100.0, speed, frozenset({speed}))
    assert pacer.on_frame(speed, 10.0) and pacer.on_frame(speed, 10.5)  # one token left
    assert pacer.on_frame(speed, 5.0)  # charged as elapsed time: -500 tokens, 5 s silent
    assert not pacer.on_frame(speed, 5.0) and pacer.on_frame(speed, 5.5)


def test_publish_pacer_trigger_rate_cap_and_fallback():
    from clutch_ros.canbus.counters import PublishPacer

    fast, speed, temps = 0x100, 0x101, 0x110
    pacer = PublishPacer(1000.0, speed, frozenset({fast, speed, temps}))
    # every trigger frame at exactly the rate publishes, jitter included
    times = [0.001 * k + (0.0003 if k % 2 else -0.0003) for k in range(1, 200)]
    assert all(pacer.on_frame(speed, t) for t in times)
    assert not pacer.on_frame(fast, times[-1] + 0.0001)  # others wait for the trigger
    # faster than the rate: the average is capped (burst of 2 first)
    pacer = PublishPacer(200.0, speed, frozenset({fast, speed}))
    published = sum(pacer.on_frame(speed, 0.001 * k) for k in range(1000))  # 1 kHz for 1 s
    assert 200 <= published <= 202
    # the trigger frame goes missing: other rig frames publish at half the rate
    pacer = PublishPacer(100.0, speed, frozenset({fast, speed}))
    published = sum(pacer.on_frame(fast, 0.001 * k) for k in range(1000))
    assert 45 <= published <= 51
    assert not any(pacer.on_frame(0x7E0, 10.0 + k) for k in range(5))  # not a rig frame
    # the whole bus pauses (a stalled rig): the next cycle's first frames wait for its
    # trigger, however long the pause; then the trigger publishes at once
    pacer = PublishPacer(100.0, speed, frozenset({fast, speed}))
    assert pacer.on_frame(speed, 1.000)
    assert not any(pacer.on_frame(fast, 1.500 + 0.001 * k) for k in range(10))  # 10 ms
    assert pacer.on_frame(speed, 1.510)
    # a trigger missing after such a pause: the fallback waits 2 / rate of frames flowing
    assert not any(pacer.on_frame(fast, 3.000 + 0.001 * k) for k in range(20))  # to 3.019
    assert pacer.on_frame(fast, 3.0201)
    # a pause within a cycle (issue 23): the bus stalls after the cycle's first frame; the
    # frames after the pause wait for their trigger however long the pause was
    pacer = PublishPacer(200.0, speed, frozenset({fast, speed}))
    assert pacer.on_frame(speed, 1.000)
    assert not pacer.on_frame(fast, 1.0004)
    start = 1.0004
    for pause in (0.0051, 0.011, 0.5):
        start += pause
        assert not any(pacer.on_frame(fast, start + 0.0004 * k) for k in range(20)), pause
        assert pacer.on_frame(speed, start + 0.0081)
        start += 0.0085
        assert not pacer.on_frame(fast, start)
    # frames flowing without the trigger still fall back after 2 / rate, pauses or not
    assert not any(pacer.on_frame(fast, 3.000 + 0.0004 * k) for k in range(25))  # to 3.0096
    assert pacer.on_frame(fast, 3.0104)
    # a trigger frame held back by the cap is flushed by the timer once the cap allows
    pacer = PublishPacer(200.0, speed, frozenset({fast, speed}))
    assert pacer.on_frame(speed, 0.0) and pacer.on_frame(speed, 0.0001)  # the burst
    assert not pacer.on_frame(speed, 0.0002) and pacer.pending  # the bus then goes quiet
    assert not pacer.flush(0.003)  # too early for the cap
    assert pacer.flush(0.008) and not pacer.pending
    assert not pacer.flush(1.0)  # nothing pending: the timer does not publish
    # timer mode: frames never publish, the timer does at the rate; nothing new: refund
    pacer = PublishPacer(10.0, None)
    assert not pacer.on_frame(speed, 0.0)
    assert pacer.flush(0.0) and pacer.flush(0.0) and not pacer.flush(0.0)
    pacer.refund()
    assert pacer.flush(0.0)
    with pytest.raises(ValueError):
        PublishPacer(0.0, speed)


def _pacer_frames(rng, n: int, keys: list[int]):
    """(bus time [s], key) of ``n`` frames: every 0-3 ms, pauses, a time going back."""
    t = 10.0
    for _ in range(n):
        t += rng.choice([0.0, 0.0005, 0.001, 0.003, 0.03, -2.0 if rng.random() < 0.01
                         else 0.002])
        yield t, rng.choice(keys)


def test_publish_pacer_fallback_due_first_publishes_what_on_frame_alone_does():
    """The bridge asks fallback_due before on_frame: the same publications, frame for frame."""
    import random

    from clutch_ros.canbus.counters import PublishPacer

    fast, speed, temps, foreign = 0x100, 0x101, 0x110, 0x7E0
    rng = random.Random(11)
    for rate in (50.0, 100.0, 1000.0):
        alone = PublishPacer(rate, speed, frozenset({fast, speed, temps}))
        asked = PublishPacer(rate, speed, frozenset({fast, speed, temps}))
        decisions = 0  # the trigger now and then: fallbacks publish too
        for t, key in _pacer_frames(rng, 5000, [fast] * 6 + [temps] * 3 + [foreign] * 3
                                    + [speed]):
            expected = alone.on_frame(key, t)
            got = (key == asked.trigger or asked.fallback_due(key, t)) and asked.on_frame(key, t)
            assert got == expected, (rate, t, key)
            decisions += expected
        assert decisions > 50  # publications happened, fallback and trigger alike


def test_publish_pacer_trigger_held_first_leaves_what_on_frame_alone_does():
    """The bridge asks trigger_held before on_frame: same decisions, same state, frame by frame."""
    import random

    from clutch_ros.canbus.counters import PublishPacer

    fast, speed, temps = 0x100, 0x101, 0x110
    rng = random.Random(12)
    for rate in (50.0, 100.0, 1000.0):
        alone = PublishPacer(rate, speed, frozenset({fast, speed, temps}))
        asked = PublishPacer(rate, speed, frozenset({fast, speed, temps}))
        held = 0
        for step, (t, key) in enumerate(_pacer_frames(rng, 8000, [fast, temps, speed, speed])):
            if step % 97 == 0:  # the bridge's slow timer
                assert alone.flush(t) == asked.flush(t)
            expected = alone.on_frame(key, t)
            if key == asked.trigger and asked.trigger_held(t):
                got, held = False, held + 1
            else:
                got = asked.on_frame(key, t)
            assert got == expected, (rate, t, key)
            assert vars(asked) == vars(alone), (rate, t, key)
        assert held > 100  # the pre-check did decline triggers


def test_publish_pacer_until_allowed_is_the_first_moment_any_frame_can_publish():
    """The bridge's receive thread sleeps until then: no publication may fall before it."""
    import copy

    from clutch_ros.canbus.counters import PublishPacer

    fast, speed = 0x100, 0x101
    pacer = PublishPacer(100.0, speed, frozenset({fast, speed}))
    assert pacer.until_allowed(0.0) == 0.0  # nothing published yet
    waits = []
    for k in range(400):  # RigFast and RigSpeed at 1 kHz, the trigger missing for a while
        now = 0.001 * k
        wait = pacer.until_allowed(now)
        waits.append(wait)
        if wait > 0.0:
            for key in (speed, fast):  # neither the trigger nor a fallback frame before it
                early = copy.deepcopy(pacer)
                assert not early.on_frame(key, now + wait - 1e-6)
            on_time = copy.deepcopy(pacer)
            assert on_time.on_frame(speed, now + wait + 1e-9)
        pacer.on_frame(fast, now)
        if not 100 <= k < 200:
            pacer.on_frame(speed, now + 0.0002)
    assert max(waits) == pytest.approx(0.0092, abs=1e-6)  # a token per 10 ms, 0.8 ms gone
    assert 0.5 < sum(w > 0.0 for w in waits) / len(waits) < 1.0


def test_apply_frames_leaves_what_feeding_the_same_frames_leaves(db):
    """The compiled intake's way in (``counter_state``, ``apply_frames``) against ``feed``.

    Two RigFast and a RigSpeed frame (counters 3 then 5: one lost frame), and two foreign
    frames: fed to one assembler, described to another as the intake's kernel would.
    """
    from clutch_ros.canbus.counters import UNKNOWN_ID_CAPACITY

    fast, speed = db.frame("RigFast").key, db.frame("RigSpeed").key
    frames = rig_frames(db, t=1.0, counter=3)[:2] + [rig_frames(db, t=1.002, counter=5)[0]]
    fed, applied = RigStateAssembler(db), RigStateAssembler(db)
    for msg in frames:
        fed.feed(msg)
    for key in (0x700, 0x700):
        fed.feed(can.Message(arbitration_id=key, is_extended_id=False, data=bytes(8)))
    with applied.lock:
        assert applied.counter_state([fast, speed]) == ([None, None], None)
        applied.apply_frames(
            (5, 5, 3, 1, 0), [(0x700, 2)], [(fast, 2, (1.002, 5)), (speed, 1, (1.0, 3))],
            1.002, [("actuating_pressure", -1, 20e5), ("measured_torque", -1, 456.7),
                    ("has_measured_torque", -1, True), ("input_speed", -1, 5.236),
                    ("output_speed", -1, -0.5)],
            (True, False), [(fast, 1.002), (speed, 1.0)])
        assert applied.counter_state([fast, speed, 0x123]) == (
            [(1.002, 5), (1.0, 3), None], 1.002)
    assert applied.counters() == fed.counters()
    a, f = applied.snapshot(), fed.snapshot()
    for name in ("actuating_pressure", "measured_torque", "has_measured_torque", "input_speed",
                 "output_speed", "slip_speed", "stamp", "stale_mask", "ages"):
        assert getattr(a, name) == pytest.approx(getattr(f, name), abs=1e-4), name
    assert applied.cycle_time(fast) == pytest.approx(0.001)
    # an array element: the array is made (NaN elsewhere); the unknown table stays bounded
    with applied.lock:
        applied.apply_frames((0, 0, 0, 0, 0), [], [], None, [("ff_voltages", 2, 1.5)],
                             (False, False), [])
        applied.apply_frames((0, 0, 0, 0, 0), [(0x7000 + i, 3) for i in
                                               range(UNKNOWN_ID_CAPACITY + 1)],
                             [], None, [], (False, False), [])
    s, c = applied.snapshot(), applied.counters()
    assert s.ff_voltages[2] == 1.5 and sum(math.isnan(v) for v in s.ff_voltages) == 7
    assert c.unknown_frames == 2 + 3 * (UNKNOWN_ID_CAPACITY + 1)
    assert c.unknown_untracked == 2 * 3  # two new keys: 0x700 holds one of the places
