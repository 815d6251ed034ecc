"""The compiled intake (bridge.compiled) against the can_bridge's Python receive path.

Both run the node's own receive code (``ReceiveSide._on_frames``) on the same traffic, in the
same batches: a rig at 1 kHz / 100 Hz / 10 Hz with rolling counters and checksums, lost and
repeated frames, pauses and a clock that jumps back, the trigger frame missing for a while,
junk between (foreign and extended identifiers, error, remote and FD frames, bad lengths, bad
checksums, values out of range, foreign pump requests). Every published rig_state, every
counter, the pacer's state and the final live sample must be equal -- the kernel takes the
clean frames, Python the rest.
"""

from __future__ import annotations

import dataclasses
import math
import random
import threading

import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.batch import RawFrame, message_frame
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.canbus.dbc import RigDatabase, crc8_sae_j1850
from clutch_ros.canbus.intake import CompiledIntake
from clutch_ros.nodes.can_bridge_receive import ReceiveSide
from clutch_ros.nodes.can_bridge_state import BridgeState
from tests.canbus.fuzzgen import _random_values, generate

PUMP_KEY = 128  # PumpRequest (params/rig.dbc)


class _Publisher:
    def __init__(self) -> None:
        self.samples: list = []

    def publish(self, item) -> None:
        self.samples.append(item)


class _Receiver(ReceiveSide):
    """The can_bridge's receive side without ROS: published samples are kept."""

    def __init__(self, db: RigDatabase, compiled: bool, rate: float, trigger: int | None,
                 active: bool = True) -> None:
        self.state = BridgeState(sources=None)  # type: ignore[arg-type]
        st = self.state
        st.assembler = RigStateAssembler(db)
        st.pacer = PublishPacer(rate, trigger, frozenset(st.assembler.map.writes))

        class _Gate:  # the gate's codec key is all the receive side reads
            codec = type("C", (), {"spec": type("S", (), {"key": PUMP_KEY})})

        st.gate = _Gate()  # type: ignore[assignment]
        st.active = active
        st.offset = 0.0
        if compiled:
            st.intake = CompiledIntake(st.assembler, st.pacer, (PUMP_KEY,))
            assert st.intake.ready
        self._lock = threading.Lock()
        self._rx_stop = threading.Event()
        self._sim_time, self._time_floor, self._cfg = False, 0.0, {}
        self._raw_pub = None
        self._rig_pub = _Publisher()
        self._rig_encode = lambda sample, stamp: sample
        self._node_time = lambda: 0.0

    def get_logger(self):  # pragma: no cover - not reached by these frames
        raise AssertionError("no log expected")


def _traffic(seed: int, seconds: float, db: RigDatabase) -> list[RawFrame]:
    """Return a rig's frames over ``seconds`` of bus time, junk between (module docstring)."""
    rng = random.Random(seed)
    junk, _ = generate(seed, int(seconds * 400), db)
    junk_iter = iter(junk)
    counters: dict[str, int] = {}
    frames: list[RawFrame] = []
    t, step = 1000.0 + rng.random(), 0.001
    periods = {"RigFast": 1, "RigSpeed": 1, "PumpStatus": 10, "FlexiForceFront": 10,
               "FlexiForceRear": 10, "WheelSpeeds": 10, "TorqueRequest": 10,
               "RigTemperatures": 100}
    outage = 0  # ticks left without RigSpeed (the usual trigger: the fallback publishes)
    for tick in range(int(seconds / step)):
        outage = max(outage - 1, 0)
        if rng.random() < 0.003:
            outage = rng.randint(20, 150)
        if rng.random() < 0.002:  # a pause of the whole bus, or the clock jumping back
            t += rng.choice([0.05, 0.3, -0.2])
        t += step
        for name, period in periods.items():
            if tick % period or (outage and name == "RigSpeed"):
                continue
            spec = db.frame(name)
            counter = None
            if spec.counter_signal:
                counter = counters.get(name, rng.randint(0, 15))
                counters[name] = (counter + (2 if rng.random() < 0.01 else 1)) % 16
                if rng.random() < 0.005:  # repeated
                    counters[name] = counter
            values = _random_values(rng, db, name)
            payload = bytearray(db.encode(name, values, counter=counter))
            if rng.random() < 0.003 and spec.checksum_signal:
                payload[3] ^= 0x10
                assert crc8_sae_j1850(payload[1:]) != payload[0] or True
            if rng.random() < 0.003 and name == "RigTemperatures":
                payload[0:2] = b"\xff\x7f"  # LamellaTemperature far above its DBC range
            key = spec.key
            frames.append((t + rng.random() * 2e-4, key, False, False, False, False,
                           len(payload), bytes(payload)))
        while rng.random() < 0.4:
            msg = next(junk_iter, None)
            if msg is None:
                break
            frame = message_frame(msg)
            frames.append((t, *frame[1:]))
        if rng.random() < 0.01:  # a foreign pump request
            frames.append((t, PUMP_KEY, False, False, False, False, 8, bytes(8)))
    return frames


def _foreign_burst(frames: list[RawFrame], db: RigDatabase, count: int) -> list[RawFrame]:
    """Insert ``count`` frames of distinct foreign identifiers in the middle of ``frames``.

    More keys than one kernel run holds (64) and than the counters track one by one (256).
    """
    known = db.keys
    ids = [i for i in range(0x800) if i not in known][:count]
    middle = len(frames) // 2
    t = frames[middle][0]
    burst = [(t, i, False, False, False, False, 1, b"\x01") for i in ids]
    return frames[:middle] + burst + burst[:50] + frames[middle:]


def _batches(frames: list[RawFrame], seed: int) -> list[list[RawFrame]]:
    rng = random.Random(seed + 1)
    out, i = [], 0
    while i < len(frames):
        n = rng.choice([1, 2, 5, 14, 18, 30, 64])
        out.append(frames[i:i + n])
        i += n
    return out


def _pacer_state(pacer: PublishPacer) -> list[float]:
    out = [0.0] * 8
    pacer.export_state(out)
    return out


def _same(a, b) -> bool:
    """Equal values, NaN equal to NaN (a sample's fields)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _assert_samples_equal(got, want) -> None:
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        for f in dataclasses.fields(w):
            assert _same(getattr(g, f.name), getattr(w, f.name)), (i, f.name)


@pytest.fixture(scope="module")
def db() -> RigDatabase:
    return RigDatabase()


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5, 6])
@pytest.mark.parametrize(("rate", "trigger_name", "active"), [
    (200.0, "RigSpeed", True), (100.0, "RigFast", True), (1000.0, "RigSpeed", True),
    (50.0, None, True), (200.0, "RigSpeed", False), (200.0, "WheelSpeeds", True)])
def test_compiled_intake_is_the_python_path(db, seed, rate, trigger_name, active) -> None:
    trigger = db.frame(trigger_name).key if trigger_name else None
    frames = _traffic(seed, 1.5, db)
    if seed == 6:
        frames = _foreign_burst(frames, db, 400)
    python = _Receiver(db, False, rate, trigger, active)
    compiled = _Receiver(db, True, rate, trigger, active)
    for batch in _batches(frames, seed):
        python._on_frames(batch)
        compiled._on_frames(batch)
    p, c = python.state, compiled.state
    if active and trigger is not None:
        assert len(python._rig_pub.samples) > 40  # (the pacer published along the way)
    _assert_samples_equal(compiled._rig_pub.samples, python._rig_pub.samples)
    assert c.assembler.counters() == p.assembler.counters()
    assert c.assembler.counters().decoded_frames > (0.45 if seed == 6 else 0.6) * len(frames)
    if seed == 6:  # (the burst: every count kept, the untracked ones summed)
        assert c.assembler.counters().unknown_untracked > 100
    assert _pacer_state(c.pacer) == pytest.approx(_pacer_state(p.pacer), nan_ok=True, rel=0)
    assert c.foreign_pump_requests == p.foreign_pump_requests
    assert (p.foreign_pump_requests > 0) == active
    assert c.intake.taken > 0.6 * len(frames)  # the kernel took the clean and foreign frames
    assert c.published == p.published
    _assert_samples_equal([c.assembler.snapshot()], [p.assembler.snapshot()])
