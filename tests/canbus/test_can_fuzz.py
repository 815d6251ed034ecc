"""Fuzz: random IDs, DLCs, payloads, error, remote and FD frames; counters must be exact."""

import json
import math
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.bus import BusConfig, ReconnectingBus
from clutch_ros.canbus.pump_gate import PumpCommandGate, PumpGateConfig

from .fuzzgen import check_counters, check_last_values, generate

REPO = Path(__file__).resolve().parents[2]


def wait_for(predicate, timeout):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


@pytest.mark.parametrize("seed", range(8))
def test_fuzz_direct_feed(db, seed):
    frames, expected = generate(seed, 2000, db)
    assembler = RigStateAssembler(db, socketcan_error_frames=True)
    for msg in frames:
        assembler.feed(msg)
    counters = assembler.counters()
    check_counters(counters, expected)
    assert counters.frames_total == (
        counters.error_frames + counters.remote_frames + counters.data_frames
    )
    assert counters.data_frames == (
        counters.decoded_frames + counters.unknown_frames + counters.decode_errors
    )
    check_last_values(assembler.snapshot(), expected, db)


def test_fuzz_counter_check_can_fail(db):
    """The oracle notices a single frame miscounted (guards against a vacuous fuzz test)."""
    frames, expected = generate(99, 500, db)
    assembler = RigStateAssembler(db, socketcan_error_frames=True)
    for msg in frames[:-1]:
        assembler.feed(msg)
    with pytest.raises(AssertionError):
        check_counters(assembler.counters(), expected)


def test_fuzz_virtual_bus_high_rate(db, channel):
    """Thousands of frames as fast as python-can sends them, through a Notifier."""
    frames, expected = generate(1234, 6000, db)
    assembler = RigStateAssembler(db, socketcan_error_frames=True)
    config = BusConfig(interface="virtual", channel=channel)
    with ReconnectingBus(config) as rx, can.Bus(interface="virtual", channel=channel) as tx:
        notifier = can.Notifier(rx, [assembler], timeout=0.05)
        try:
            start = time.perf_counter()
            for msg in frames:
                tx.send(msg)
            sent_rate = len(frames) / (time.perf_counter() - start)
            assert wait_for(lambda: assembler.counters().frames_total == len(frames), 20.0)
        finally:
            notifier.stop()
        assert rx.connects == 1 and rx.disconnects == 0
    assert sent_rate > 1000.0  # "high rate": far above the rig's 2.6 kHz nominal load
    check_counters(assembler.counters(), expected)
    check_last_values(assembler.snapshot(), expected, db)


def test_fuzz_udp_multicast_between_processes(db):
    """A second process sends fuzz traffic over udp_multicast; we answer with pump requests."""
    pytest.importorskip("msgpack", reason="python-can's udp_multicast needs msgpack")
    rng = random.Random()
    group = f"239.{rng.randint(1, 254)}.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
    port = rng.randint(20000, 60000)
    count, seed = 1500, rng.randrange(1 << 30)
    frames, expected = generate(seed, count, db)
    assembler = RigStateAssembler(db, socketcan_error_frames=True)
    config = BusConfig(interface="udp_multicast", channel=group, fd=True, extra={"port": port})
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with ReconnectingBus(config) as bus:
        notifier = can.Notifier(bus, [assembler], timeout=0.05)
        proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).with_name("udp_peer.py")), group, str(port),
             str(seed), str(count), "2500", "5"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env,
        )
        try:
            assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
            assert wait_for(lambda: assembler.counters().frames_total == count, 30.0), (
                assembler.counters()
            )
            check_counters(assembler.counters(), expected)
            check_last_values(assembler.snapshot(), expected, db)
            # udp_multicast loops our own frames back: the pump requests below add 5 frames
            gate = PumpCommandGate(time.monotonic, PumpGateConfig(rate_limit_up=math.inf))
            sent = []
            for i in range(5):  # a change (first), then periodic frames of the same request
                out = gate.submit(12.5e5, time.time()) if i == 0 else gate.tick()
                assert bus.try_send(out.frame)
                sent.append(out.frame.data[1] & 0x0F)
                time.sleep(0.01)
            stdout, stderr = proc.communicate(timeout=30)
        finally:
            notifier.stop()
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, stderr
    received = json.loads(stdout.strip().splitlines()[-1])
    assert [r[1] for r in received] == sent
    for pressure, _counter, checksum_ok in received:
        assert checksum_ok
        assert pressure == pytest.approx(12.5e5)
