"""Deterministic fuzz traffic for the CAN tests, with its own oracle of the expected counters.

Every generated frame is tagged with what it must count as when it was built, so the
expectation does not re-implement the assembler's classification. Valid rig frames are
interleaved with junk; their rolling counters stay consecutive (a corrupted PumpStatus reuses
the counter of the next valid one), so no drop must be reported.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import dataclass, field

import can

from clutch_ros.canbus.counters import UNKNOWN_ID_CAPACITY
from clutch_ros.canbus.dbc import RigDatabase, crc8_sae_j1850

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@dataclass
class Expected:
    frames_total: int = 0
    error_frames: int = 0
    bus_off_frames: int = 0
    remote_frames: int = 0
    data_frames: int = 0
    fd_frames: int = 0
    unknown_frames: int = 0
    decoded_frames: int = 0
    decode_errors: Counter = field(default_factory=Counter)
    unknown_ids: Counter = field(default_factory=Counter)  # in order of first appearance
    last: dict = field(default_factory=dict)  # message name -> SI values sent last


def _random_values(rng: random.Random, db: RigDatabase, name: str) -> dict[str, float]:
    spec = db.frame(name)
    values: dict[str, float] = {}
    for sig in spec.signals:
        if sig.name in (spec.counter_signal, spec.checksum_signal):
            continue
        steps = round((sig.maximum - sig.minimum) / sig.resolution)
        values[sig.name] = sig.minimum + rng.randint(0, steps) * sig.resolution
        if sig.resolution == 1.0:
            values[sig.name] = int(values[sig.name])
    return values


def generate(seed: int, count: int, db: RigDatabase) -> tuple[list[can.Message], Expected]:
    """Return ``count`` frames from ``seed`` and the counters they must produce."""
    rng = random.Random(seed)
    exp = Expected()
    known = db.keys
    std_unknown = [i for i in range(0x800) if i not in known]
    counters: dict[str, int] = {}
    names = [spec.name for spec in db.frames if spec.name != "PumpRequest"]
    frames: list[can.Message] = []

    def valid(name: str) -> can.Message:
        spec = db.frame(name)
        values = _random_values(rng, db, name)
        counter = None
        if spec.counter_signal:
            counter = counters.get(name, rng.randint(0, 15))
            counters[name] = (counter + 1) % 16
        exp.last[name] = values
        exp.decoded_frames += 1
        return db.make_message(name, values, counter=counter)

    for _ in range(count):
        kind = rng.choices(
            ["valid", "unknown_std", "unknown_ext", "bad_dlc", "bad_crc", "error", "remote",
             "fd_unknown", "fd_known_long"],
            weights=[30, 12, 8, 6, 4, 8, 8, 8, 4],
        )[0]
        if kind == "valid":
            msg = valid(rng.choice(names))
        elif kind in ("unknown_std", "unknown_ext"):
            ext = kind == "unknown_ext"
            arb = rng.randrange(1 << 29) if ext else rng.choice(std_unknown)
            data = rng.randbytes(rng.randint(0, 8))
            msg = can.Message(arbitration_id=arb, is_extended_id=ext, data=data)
            exp.unknown_frames += 1
            exp.unknown_ids[arb | (0x80000000 if ext else 0)] += 1
        elif kind == "bad_dlc":
            spec = db.frame(rng.choice(names))
            data = rng.randbytes(rng.choice([0, 1, 2, 3, 4, 5, 6, 7]))
            msg = can.Message(arbitration_id=spec.frame_id, is_extended_id=False, data=data)
            exp.decode_errors["dlc"] += 1
        elif kind == "bad_crc":
            spec = db.frame("PumpStatus")
            counter = counters.get("PumpStatus", 0)  # not advanced: the next valid one reuses it
            payload = bytearray(
                db.encode("PumpStatus", _random_values(rng, db, "PumpStatus"), counter=counter)
            )
            payload[rng.randrange(8)] ^= 1 << rng.randrange(8)
            assert crc8_sae_j1850(payload[1:]) != payload[0]
            msg = can.Message(arbitration_id=spec.frame_id, is_extended_id=False, data=payload)
            exp.decode_errors["checksum"] += 1
        elif kind == "error":
            arb = rng.randrange(1 << 29)
            msg = can.Message(
                arbitration_id=arb, is_extended_id=True, is_error_frame=True,
                data=rng.randbytes(8),
            )
            exp.error_frames += 1
            exp.bus_off_frames += bool(arb & 0x40)
        elif kind == "remote":
            ext = rng.random() < 0.5
            arb = rng.randrange(1 << 29) if ext else rng.randrange(0x800)
            msg = can.Message(
                arbitration_id=arb, is_extended_id=ext, is_remote_frame=True,
                dlc=rng.randint(0, 8),
            )
            exp.remote_frames += 1
        elif kind == "fd_unknown":
            ext = rng.random() < 0.5
            arb = rng.randrange(1 << 29) if ext else rng.choice(std_unknown)
            msg = can.Message(
                arbitration_id=arb, is_extended_id=ext, is_fd=True,
                bitrate_switch=rng.random() < 0.5, data=rng.randbytes(rng.choice(FD_LENGTHS)),
            )
            exp.unknown_frames += 1
            exp.unknown_ids[arb | (0x80000000 if ext else 0)] += 1
            exp.fd_frames += 1
        else:  # fd_known_long
            spec = db.frame(rng.choice(names))
            msg = can.Message(
                arbitration_id=spec.frame_id, is_extended_id=False, is_fd=True,
                data=rng.randbytes(rng.choice(FD_LENGTHS[9:])),
            )
            exp.decode_errors["dlc"] += 1
            exp.fd_frames += 1
        frames.append(msg)
    exp.frames_total = len(frames)
    exp.data_frames = exp.frames_total - exp.error_frames - exp.remote_frames
    return frames, exp


def check_counters(counters, exp: Expected) -> None:
    """Assert that an assembler's CounterSnapshot matches the oracle exactly."""
    assert counters.frames_total == exp.frames_total
    assert counters.error_frames == exp.error_frames
    assert counters.bus_off_frames == exp.bus_off_frames
    assert counters.remote_frames == exp.remote_frames
    assert counters.data_frames == exp.data_frames
    assert counters.fd_frames == exp.fd_frames
    assert counters.unknown_frames == exp.unknown_frames
    assert counters.decoded_frames == exp.decoded_frames
    assert counters.decode_errors_by_reason == {k: v for k, v in exp.decode_errors.items() if v}
    # exact counts for the first UNKNOWN_ID_CAPACITY distinct keys, the rest summed
    tracked = dict(list(exp.unknown_ids.items())[:UNKNOWN_ID_CAPACITY])
    assert counters.unknown_id_counts == tracked
    assert counters.unknown_untracked == exp.unknown_frames - sum(tracked.values())
    assert counters.dropped_frames == 0
    assert counters.counter_repeats == 0
    assert counters.listener_errors == 0


def check_last_values(sample, exp: Expected, db: RigDatabase) -> None:
    """Assert that a RigSample holds the last valid values of each rig frame (within resolution)."""
    def close(actual: float, name: str, signal: str) -> None:
        tol = db.signal(signal).resolution * 0.51 + 1e-9
        assert abs(actual - exp.last[name][signal]) <= tol, (name, signal, actual)

    if "RigFast" in exp.last:
        close(sample.actuating_pressure, "RigFast", "ActuatingPressure")
        close(sample.measured_torque, "RigFast", "MeasuredTorque")
    if "RigSpeed" in exp.last:
        close(sample.input_speed, "RigSpeed", "InputShaftSpeed")
        close(sample.output_speed, "RigSpeed", "OutputShaftSpeed")
    if "RigTemperatures" in exp.last:
        close(sample.lamella_temperature, "RigTemperatures", "LamellaTemperature")
        close(sample.oil_temperature, "RigTemperatures", "OilTemperature")
    if "PumpStatus" in exp.last:
        close(sample.pump_current, "PumpStatus", "PumpSts_Current")
    if "WheelSpeeds" in exp.last:
        for value, sig in zip(sample.wheel_speeds, ("WheelSpeedFL", "WheelSpeedFR",
                                                    "WheelSpeedRL", "WheelSpeedRR")):
            close(value, "WheelSpeeds", sig)
    if "FlexiForceFront" in exp.last:
        for i in range(4):
            close(sample.ff_voltages[i], "FlexiForceFront", f"FF_Front{i + 1}")
    if "TorqueRequest" in exp.last:
        close(sample.torque_request, "TorqueRequest", "TorqueRequest")
