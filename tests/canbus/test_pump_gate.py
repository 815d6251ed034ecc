"""PumpCommandGate: every frame within limits; admission by stamp; frames at the cycle; watchdog.

The gate's defaults are the configuration the can_bridge node runs (its declared ``pump.*``
defaults give exactly ``PumpGateConfig()``, checked here); tests that do not name a limit run
with them.
"""

import math
import random

import pytest
from numpy.testing import assert_allclose

from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.canbus.pump_gate import PUMP_PERIOD, PumpCommandGate, PumpGateConfig
from clutch_ros.errors import ConfigError

BAR = 1e5
DEFAULT = PumpGateConfig()  # what the node runs


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def make_gate(db, clock, **kwargs):
    """Return a gate whose command stamps share ``clock`` (as a node's share its clock)."""
    config = PumpGateConfig(**kwargs)
    return PumpCommandGate(clock, config, PumpRequestCodec(db, config.max_pressure),
                           stamp_clock=clock)


def command(gate, clock, pressure):
    """Submit ``pressure`` stamped now; return the frame sent for it (immediate or next tick)."""
    out = gate.submit(pressure, clock.t)
    return out if out is not None else gate.tick()


def decoded(db, out):
    pressure, counter, ok = PumpRequestCodec(db).decode(out.frame)
    assert ok
    assert pressure == pytest.approx(out.pressure, abs=1e-6)
    return pressure, counter


def test_no_command_yet_sends_zero(db):
    gate = make_gate(db, FakeClock())
    out = gate.tick()
    assert out.pressure == 0.0 and out.limited and "no command" in out.reason
    assert decoded(db, out) == (0.0, 0)


def test_plain_command_passes_unchanged(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf)
    out = gate.submit(12.3456e5, clock.t)
    assert out.pressure == pytest.approx(12.3456e5, abs=50.0)
    assert not out.limited and out.reason == ""
    frame, pressure, limited, reason = out  # the tuple form the bridge unpacks
    assert frame is out.frame and pressure == out.pressure


@pytest.mark.parametrize(
    "value, words",
    [(math.nan, "not finite"), (math.inf, "not finite"), (-math.inf, "not finite"),
     (-3e5, "negative"), (None, "not finite"), ("12 bar", "not finite")],
)
def test_bad_commands_give_zero_with_reason(db, value, words):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf)
    command(gate, clock, 20e5)
    clock.t += 0.01
    gate.tick()
    out = command(gate, clock, value)
    assert out.pressure == 0.0 and out.limited and words in out.reason
    assert decoded(db, out)[0] == 0.0
    assert gate.rejected_commands == 1
    clock.t += 0.01
    assert gate.tick().pressure == 0.0  # the reason stays until the next command


@pytest.mark.parametrize("value", [40.0001e5, 1e9, 1e300, 5e5 * 1e6])
def test_huge_commands_are_clamped(db, value):
    clock = FakeClock()
    gate = make_gate(db, clock, max_pressure=40e5, rate_limit_up=math.inf)
    out = command(gate, clock, value)
    assert out.pressure == pytest.approx(40e5) and out.limited and "clamped" in out.reason
    assert decoded(db, out)[0] <= 40e5


def test_watchdog_zeroes_within_timeout(db):
    clock = FakeClock()
    timeout = DEFAULT.watchdog_timeout  # the node's (0.2 s)
    gate = make_gate(db, clock, rate_limit_up=math.inf)
    command(gate, clock, 30e5)
    t0 = clock.t
    outputs = []
    for _ in range(round(timeout / PUMP_PERIOD) + 10):  # 10 ms PumpRequest cycle
        clock.t += PUMP_PERIOD
        outputs.append((clock.t - t0, gate.tick()))
    held = [o for dt, o in outputs if dt <= timeout - 1e-9]
    tripped = [(dt, o) for dt, o in outputs if o.pressure == 0.0]
    assert len(held) >= round(timeout / PUMP_PERIOD) - 1
    assert all(o.pressure == pytest.approx(30e5) for o in held)
    first_dt, first = tripped[0]
    assert first_dt <= timeout + PUMP_PERIOD + 1e-9  # zero within the timeout plus one cycle
    assert "watchdog" in first.reason and first.limited
    assert all(o.pressure == 0.0 for dt, o in outputs if dt > first_dt)
    assert gate.watchdog_trips == 1  # one trip per command gap, not one per frame
    clock.t += 0.01
    assert command(gate, clock, 10e5).pressure == pytest.approx(10e5)
    clock.t += timeout + 0.3
    gate.tick()
    assert gate.watchdog_trips == 2


def test_rate_limit_up_and_down(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=100 * BAR, rate_limit_down=50 * BAR,
                     watchdog_timeout=10.0)
    command(gate, clock, 0.0)
    previous = 0.0
    clock.t += 0.01
    gate.tick()  # a new period: the next change may go out at once
    gate.submit(20e5, clock.t)
    ramp = []
    for _ in range(40):
        clock.t += 0.01
        out = gate.tick()
        assert out.pressure - previous <= 1 * BAR + 100.0  # 100 bar/s * 10 ms (+resolution)
        ramp.append(out)
        previous = out.pressure
    assert ramp[0].limited and "rate limited" in ramp[0].reason
    assert ramp[-1].pressure == pytest.approx(20e5) and not ramp[-1].limited
    gate.submit(10e5, clock.t)
    clock.t += 0.01
    out = gate.tick()
    assert out.pressure == pytest.approx(19.5e5)  # 50 bar/s down
    out = gate.submit(math.nan, clock.t)  # fail-safe: straight to 0 despite the down limit
    assert out.pressure == 0.0


def test_counter_rolls_and_checksums_hold(db):
    clock = FakeClock()
    gate = make_gate(db, clock)
    counters = []
    for i in range(40):
        clock.t += 0.01
        out = gate.submit(5e5 + 100.0 * i, clock.t) if i % 3 == 0 else gate.tick()
        counters.append(decoded(db, out)[1])
    assert counters == [i % 16 for i in range(40)]
    assert gate.frames == 40


# -- admission (finding 2) -------------------------------------------------------------------

def test_stale_future_out_of_order_and_unstamped_commands_are_refused(db):
    clock = FakeClock(1000.0)
    gate = make_gate(db, clock, rate_limit_up=math.inf, watchdog_timeout=0.2,
                     future_tolerance=0.05)
    assert gate.submit(10e5, clock.t - 10.0) is None  # 10 s old
    assert gate.submit(10e5, clock.t + 10.0) is None  # 10 s ahead
    assert gate.submit(10e5, None) is None  # unstamped, refused by default
    assert gate.submit(10e5, math.nan) is None
    assert gate.refused == {"stale": 1, "future": 1, "unstamped": 2}
    assert "not finite" in gate.last_refusal
    assert gate.commands == 0 and gate.tick().pressure == 0.0  # nothing admitted: 0 bar
    # within the limits: admitted (0.19 s old, 0.04 s ahead)
    assert gate.submit(12e5, clock.t - 0.19).pressure == pytest.approx(12e5)
    clock.t += 0.01
    gate.tick()
    assert gate.submit(13e5, clock.t + 0.04).pressure == pytest.approx(13e5)
    # older than the last admitted stamp: refused, even though it is fresh
    clock.t += 0.01
    gate.tick()
    assert gate.submit(14e5, clock.t - 0.001) is None
    assert gate.refused["out_of_order"] == 1 and "older than the last" in gate.last_refusal
    assert gate.tick().pressure == pytest.approx(13e5)
    # the same stamp twice is admitted (a coarse simulated clock)
    assert gate.submit(15e5, clock.t + 0.04) is not None


def test_refused_commands_do_not_feed_the_watchdog(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf, watchdog_timeout=0.2)
    command(gate, clock, 20e5)
    pressures = []
    for k in range(60):  # 0.6 s of stale and future commands at 1 kHz-ish, ticks at 100 Hz
        clock.t += 0.01
        for j in range(10):
            gate.submit(20e5, clock.t - 5.0 if j % 2 else clock.t + 5.0)
        pressures.append((0.01 * (k + 1), gate.tick().pressure))
    assert all(p == pytest.approx(20e5) for t, p in pressures if t <= 0.2 - 1e-9)
    assert all(p == 0.0 for t, p in pressures if t > 0.21 + 1e-9)
    assert gate.refused["stale"] == gate.refused["future"] == 300


def test_unstamped_commands_admitted_when_configured(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf, accept_unstamped=True)
    assert gate.submit(7e5).pressure == pytest.approx(7e5)
    assert not gate.refused


# -- frame rate (finding 4) ------------------------------------------------------------------

def test_10_khz_commands_give_at_most_two_frames_per_period_and_no_backlog(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf, watchdog_timeout=0.2)
    frames = []
    for k in range(10_000):  # 1 s of commands at 10 kHz, a new value each time
        clock.t = 100.0 + k * 1e-4
        out = gate.submit(10e5 + 100.0 * (k % 300), clock.t)
        if out is not None:
            frames.append(out)
        if k % 100 == 99:  # the 10 ms PumpRequest timer
            frames.append(gate.tick())
    assert len(frames) <= 200, len(frames)
    assert gate.immediate_frames <= 100 and gate.commands == 10_000
    # the last admitted command goes out with the next tick; nothing is queued behind it
    clock.t += 0.01
    last = gate.tick()
    assert last.pressure == pytest.approx(10e5 + 100.0 * (9_999 % 300))
    # an unchanged command makes no immediate frame at all
    before = gate.frames
    assert gate.submit(last.pressure, clock.t) is None and gate.frames == before


def test_zero_on_shutdown(db):
    clock = FakeClock()
    gate = make_gate(db, clock, rate_limit_up=math.inf)
    command(gate, clock, 25e5)
    out = gate.zero("shutdown")
    assert out.pressure == 0.0 and "shutdown" in out.reason and decoded(db, out)[0] == 0.0
    clock.t += 1.0
    assert gate.tick().pressure == 0.0 and gate.watchdog_trips == 0


@pytest.mark.parametrize("seed", range(6))
def test_fuzz_no_frame_outside_limits(db, seed):
    rng = random.Random(seed)
    max_p = rng.uniform(0.5, 60.0) * BAR
    rate = rng.choice([math.inf, rng.uniform(1, 500) * BAR])
    timeout = rng.uniform(0.02, 0.5)
    clock = FakeClock(rng.uniform(0, 1e6))
    gate = make_gate(db, clock, max_pressure=max_p, rate_limit_up=rate, watchdog_timeout=timeout)
    codec = PumpRequestCodec(db)
    specials = [math.nan, math.inf, -math.inf, -0.0, 0.0, -1e-300, 5e-324, 1e308, -1e308,
                None, "x", max_p, max_p + 1.0, max_p * 2, 60e5, 60.0001e5]
    previous, last_command, expected_counter, previous_t = 0.0, None, 0, clock.t
    for _ in range(3000):
        step = rng.choice([0.0, 0.001, 0.01, 0.01, 0.05, rng.uniform(0, 1.0), -0.01])
        clock.t += step
        if rng.random() < 0.5:
            value = rng.choice(specials) if rng.random() < 0.3 else rng.uniform(-10, 80) * BAR
            before = gate.commands
            out = gate.submit(value, clock.t + rng.choice([0.0, -0.001, -1.0, 1.0]))
            if gate.commands > before:
                last_command = clock.t
        else:
            out = gate.tick()
        if out is None:
            continue
        pressure, counter, ok = codec.decode(out.frame)
        assert ok and counter == expected_counter
        expected_counter = (expected_counter + 1) % 16
        assert 0.0 <= pressure <= max_p, (pressure, max_p)
        assert pressure == pytest.approx(out.pressure, abs=1e-6)
        assert out.limited == bool(out.reason)
        dt = clock.t - previous_t
        if math.isfinite(rate) and dt >= 0 and pressure > previous:
            assert pressure - previous <= rate * max(dt, 0.0) + codec.resolution + 1e-6
        if last_command is None or clock.t - last_command > timeout:
            assert pressure == 0.0  # no command yet, or the watchdog
        previous, previous_t = pressure, clock.t


def test_watchdog_fuzz_zero_after_timeout(db):
    """Random command gaps: any tick later than the timeout after the last command is 0 bar."""
    rng = random.Random(7)
    clock = FakeClock()
    timeout = DEFAULT.watchdog_timeout  # the node's
    gate = make_gate(db, clock, rate_limit_up=math.inf)
    last, trips = None, 0
    for _ in range(2000):
        clock.t += rng.choice([0.01, 0.03, 0.07, 0.15, 0.25])
        if rng.random() < 0.3:
            gate.submit(rng.uniform(1, 40) * BAR, clock.t)
            last = clock.t
        else:
            out = gate.tick()
            if last is not None and clock.t - last > timeout:
                trips += 1
                assert out.pressure == 0.0 and "watchdog" in out.reason
            elif last is not None:
                assert out.pressure > 0.0
    assert trips > 50  # the gaps beyond the timeout were exercised


def test_gate_config_validation(db):
    for kwargs in ({"max_pressure": 0.0}, {"max_pressure": math.nan},
                   {"rate_limit_up": 0.0}, {"rate_limit_down": math.nan},
                   {"watchdog_timeout": 0.0}, {"watchdog_timeout": math.inf},
                   {"future_tolerance": -0.1}, {"future_tolerance": math.nan}):
        with pytest.raises(ConfigError):
            PumpGateConfig(**kwargs)
    with pytest.raises(ConfigError):
        PumpCommandGate(FakeClock(), PumpGateConfig(max_pressure=70e5))


def test_a_late_frame_rises_by_one_period_at_most(db):
    """A frame after a stall carries one period's rise, not the whole stall's (the kick)."""
    clock = FakeClock()
    capped = make_gate(db, clock, rate_limit_up=90 * BAR, watchdog_timeout=10.0)  # the default
    uncapped = make_gate(db, clock, rate_limit_up=90 * BAR, watchdog_timeout=10.0,
                         max_step_interval=math.inf)
    assert capped.config.max_step_interval == PUMP_PERIOD == 0.01
    for gate in (capped, uncapped):
        command(gate, clock, 0.0)
    clock.t += 0.01
    for gate in (capped, uncapped):
        gate.tick()
        gate.submit(20e5, clock.t)
    steps = {id(g): [] for g in (capped, uncapped)}
    previous = {id(g): g.applied_pressure for g in (capped, uncapped)}
    for dt in (0.01, 0.01, 0.05, 0.01, 0.03, 0.01):  # two late ticks
        clock.t += dt
        for gate in (capped, uncapped):
            out = gate.tick()
            steps[id(gate)].append(out.pressure - previous[id(gate)])
            previous[id(gate)] = out.pressure
    # 90 bar/s x 10 ms = 0.9 bar per frame at most, late or not (+ the 100 Pa resolution)
    assert max(steps[id(capped)]) <= 0.9 * BAR + 100.0
    assert_allclose(sum(steps[id(capped)]), 6 * 0.9 * BAR, atol=200.0)  # 2 x 100 Pa rounding
    # the control: crediting the whole stall releases 4.5 bar in one frame
    assert max(steps[id(uncapped)]) >= 4.5 * BAR - 100.0
    with pytest.raises(ConfigError, match="max_step_interval"):
        PumpGateConfig(max_step_interval=0.0)


# -- the defaults the node runs (issue 25) ---------------------------------------------------

def test_the_node_declares_the_gate_defaults():
    """The can_bridge's declared pump.* defaults give exactly the gate's default config."""
    from clutch_ros.nodes.can_bridge_params import PARAMS, gate_config

    declared = {spec.name: spec.default for spec in PARAMS}
    assert gate_config(declared) == DEFAULT
    assert declared["pump.period"] == PUMP_PERIOD == DEFAULT.max_step_interval
    assert declared["pump.rise_rate_limit"] == DEFAULT.rate_limit_up
    assert declared["pump.watchdog_timeout"] == DEFAULT.watchdog_timeout
    assert declared["pump.max_pressure"] == DEFAULT.max_pressure


def test_defaults_step_ramps_within_the_rate_limit_and_stays_within_max(db):
    """A 0 -> 100 bar step with the node's defaults: 40 bar at most, 400 bar/s, one cycle each."""
    clock = FakeClock()
    gate = make_gate(db, clock)
    step = DEFAULT.rate_limit_up * PUMP_PERIOD  # 4 bar per 10 ms frame
    command(gate, clock, 0.0)
    previous, frames = 0.0, []
    for k in range(30):  # commands every cycle, a stall of 5 cycles at k = 3
        clock.t += 5 * PUMP_PERIOD if k == 3 else PUMP_PERIOD
        out = command(gate, clock, 100 * BAR)
        assert decoded(db, out)[0] <= DEFAULT.max_pressure
        assert out.pressure - previous <= step + 100.0  # late or not (+ the resolution)
        frames.append(out.pressure)
        previous = out.pressure
    assert frames[-1] == pytest.approx(DEFAULT.max_pressure)
    assert frames.index(frames[-1]) >= DEFAULT.max_pressure / step - 1  # 10 frames of ramp
