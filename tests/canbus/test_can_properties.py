"""Property-based tests (hypothesis) of the DBC codec, the assembler and the pump command gate.

For any frame or command sequence: no exception escapes, nothing non-finite (or outside the
DBC range) is published without its stale flag, and no pump frame exceeds the limit in force.
Examples are derandomized so a run is reproducible; hypothesis is pinned in requirements.txt.
"""

import math

import can
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.errors import FrameDecodeError
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.canbus.pump_gate import PumpCommandGate, PumpGateConfig
from clutch_ros.rigstate import FIELDS

DB = RigDatabase()
SETTINGS = settings(max_examples=300, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])
RIG_IDS = [spec.frame_id for spec in DB.frames]

#: RigState scalar field -> stale_mask bit of the group that feeds it
FIELD_BIT = {"actuating_pressure": 0, "measured_torque": 0, "input_speed": 1,
             "output_speed": 1, "slip_speed": 1, "lamella_temperature": 2,
             "oil_temperature": 2, "pump_current": 3, "torque_request": 7}
FIELD_SIGNAL = {f.name: f.dbc[1] for f in FIELDS if f.kind == "scalar" and f.dbc}


@st.composite
def frames(draw):
    """Any python-can frame: rig identifiers with random payloads, junk identifiers, flags."""
    ext = draw(st.booleans())
    kind = draw(st.sampled_from(["rig", "rig", "rig", "any", "error", "remote"]))
    if kind == "rig":
        arb, ext = draw(st.sampled_from(RIG_IDS)), False
    else:
        arb = draw(st.integers(0, (1 << 30) if ext else 0xFFF))
    fd = draw(st.booleans()) if kind in ("any", "rig") and draw(st.integers(0, 9)) == 0 \
        else False
    size = draw(st.sampled_from([8, 8, 8, 0, 1, 7, 9, 12, 64]))
    data = b"" if kind == "remote" else draw(st.binary(min_size=size, max_size=size))
    dlc = draw(st.sampled_from([len(data), len(data), draw(st.integers(0, 64))]))
    return can.Message(arbitration_id=arb, is_extended_id=ext, data=data, dlc=dlc, is_fd=fd,
                       is_error_frame=kind == "error", is_remote_frame=kind == "remote",
                       timestamp=draw(st.floats(0.0, 10.0)))


@SETTINGS
@given(arb=st.sampled_from(RIG_IDS), data=st.binary(min_size=0, max_size=64))
def test_codec_decodes_in_range_finite_values_or_raises_its_own_error(arb, data):
    try:
        values = DB.decode(arb, data)
    except FrameDecodeError as err:
        assert err.reason in ("dlc", "checksum", "payload", "range")
        return
    spec = DB.lookup(arb)
    for sig in spec.signals:
        value = values[sig.name]
        assert math.isfinite(value)
        assert sig.minimum - sig.resolution <= value <= sig.maximum + sig.resolution


def _check_sample(sample) -> None:
    """Every non-finite or out-of-range value of a sample is flagged by its group's bit."""
    for name, bit in FIELD_BIT.items():
        value = getattr(sample, name)
        flagged = bool(sample.stale_mask & (1 << bit))
        if not math.isfinite(value):
            assert flagged, (name, value, bin(sample.stale_mask))
        elif name in FIELD_SIGNAL:
            sig = DB.signal(FIELD_SIGNAL[name])
            assert sig.minimum - sig.resolution <= value <= sig.maximum + sig.resolution
    for part, bit in ((sample.ff_voltages[:4], 4), (sample.ff_voltages[4:], 5)):
        if not all(math.isfinite(v) for v in part):
            assert sample.stale_mask & (1 << bit), (sample.ff_voltages, bin(sample.stale_mask))
    assert all(math.isfinite(v) for v in sample.wheel_speeds) or sample.stale_mask & 64
    assert len(sample.ff_voltages) in (0, 8) and len(sample.wheel_speeds) in (0, 4)


@SETTINGS
@given(stream=st.lists(frames(), max_size=60), now=st.floats(0.0, 12.0))
def test_assembler_never_raises_and_flags_every_bad_value(stream, now):
    assembler = RigStateAssembler(DB)
    for msg in stream:
        assembler.feed(msg)
        _check_sample(assembler.snapshot(now))
    c = assembler.counters()
    assert c.frames_total == len(stream)
    assert c.frames_total == c.error_frames + c.remote_frames + c.data_frames
    assert c.data_frames == c.decoded_frames + c.unknown_frames + c.decode_errors
    _check_sample(assembler.snapshot())


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


commands = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-1e6, 8e6),
    st.sampled_from([None, "x", 0.0, -0.0, 40e5, 60e5, 1e308]),
)
ops = st.lists(st.tuples(
    st.sampled_from(["submit", "submit", "tick"]),
    st.floats(-0.01, 0.3),  # clock step [s] (a step back too)
    commands,
    st.one_of(st.none(), st.floats(-1.0, 1.0), st.just(math.nan)),  # stamp offset [s]
), max_size=150)


@SETTINGS
@given(ops=ops, max_bar=st.floats(0.5, 60.0), rate=st.one_of(st.just(math.inf),
       st.floats(1e4, 1e8)), timeout=st.floats(0.01, 1.0), unstamped=st.booleans())
def test_gate_never_exceeds_the_limit_and_never_bursts(ops, max_bar, rate, timeout, unstamped):
    clock = Clock()
    config = PumpGateConfig(max_pressure=max_bar * 1e5, rate_limit_up=rate,
                            watchdog_timeout=timeout, accept_unstamped=unstamped)
    codec = PumpRequestCodec(DB)
    gate = PumpCommandGate(clock, config, PumpRequestCodec(DB, config.max_pressure),
                           stamp_clock=clock)
    immediate, expected_counter = 0, 0
    for op, step, value, offset in ops:
        clock.t += step
        if op == "tick":
            out, immediate = gate.tick(), 0
        else:
            stamp = None if offset is None else clock.t + offset
            out = gate.submit(value, stamp)
            immediate += out is not None
            assert immediate <= 1  # at most one extra frame between two ticks
        if out is None:
            continue
        pressure, counter, ok = codec.decode(out.frame)
        assert ok and counter == expected_counter
        expected_counter = (expected_counter + 1) % 16
        assert 0.0 <= pressure <= config.max_pressure
        assert math.isfinite(out.pressure) and out.limited == bool(out.reason)
    refused = sum(gate.refused.values())
    assert gate.commands + refused == sum(op == "submit" for op, *_ in ops)
