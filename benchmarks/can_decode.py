"""Benchmark of the CAN receive path: ``python -m benchmarks.can_decode [--json]``.

Measures, on an in-process python-can ``virtual`` bus with 8-byte rig frames:

* throughput [frames/s]: ``--frames`` frames are queued first, then drained; the bare
  python-can ``recv()`` loop versus a :class:`can.Notifier` feeding the
  :class:`~clutch_ros.canbus.assembler.RigStateAssembler` (DBC decode) while a second thread
  takes RigState snapshots at 1 kHz (what can_bridge publishes);
* latency [ms]: frames sent at a paced rate (1 kHz and 5 kHz) for ``--seconds``; the time
  from the frame's bus timestamp (set by the virtual bus on send) to the moment it was
  received (bare loop) or decoded into the assembler; median and 99th percentile.

Both paths run in the same process and run, so the figures compare like with like. No
frame may be lost (the virtual bus has an unbounded queue); lost frames are reported.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
import uuid
from dataclasses import asdict, dataclass

import can

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.dbc import RigDatabase

__all__ = ["BenchResult", "main", "run_bench"]


@dataclass
class BenchResult:
    """One measured path: throughput [frames/s], latencies [ms], frames lost."""

    path: str
    throughput: float
    lat_median_1k: float
    lat_p99_1k: float
    lat_median_5k: float
    lat_p99_5k: float
    lost: int
    snapshots_per_s: float = 0.0


def _frames(db: RigDatabase, n: int) -> list[can.Message]:
    out = []
    for i in range(n):
        if i % 2 == 0:
            values = {"ActuatingPressure": 20e5, "MeasuredTorque": 300.0, "MeasuredTorqueValid": 1}
            out.append(db.make_message("RigFast", values, counter=(i // 2) % 16))
        else:
            values = {"InputShaftSpeed": 5.0, "OutputShaftSpeed": 0.0}
            out.append(db.make_message("RigSpeed", values, counter=(i // 2) % 16))
    return out


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


class _Probe(can.Listener):
    """Feed the assembler and record frame-to-decoded latency [s]."""

    def __init__(self, assembler: RigStateAssembler) -> None:
        self.assembler = assembler
        self.latencies: list[float] = []
        self.count = 0
        self.last_time = 0.0

    def on_message_received(self, msg: can.Message) -> None:
        self.assembler.feed(msg)
        now = time.time()
        self.latencies.append(now - msg.timestamp)
        self.count += 1
        self.last_time = now


class _Publisher(threading.Thread):
    """Take assembler snapshots at ``rate`` [Hz] until stopped (like the RigState timer)."""

    def __init__(self, assembler: RigStateAssembler, rate: float) -> None:
        super().__init__(daemon=True)
        self.assembler, self.period = assembler, 1.0 / rate
        self.stop_event = threading.Event()
        self.count = 0
        self.elapsed = 0.0

    @property
    def rate(self) -> float:
        """Snapshots taken per second [1/s]."""
        return self.count / self.elapsed if self.elapsed > 0 else 0.0

    def run(self) -> None:
        start = next_t = time.perf_counter()
        while not self.stop_event.is_set():
            self.assembler.snapshot(time.time())
            self.count += 1
            next_t += self.period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            self.elapsed = time.perf_counter() - start


def _send_paced(bus: can.BusABC, frames: list[can.Message], rate: float) -> None:
    start = time.perf_counter()
    for i, msg in enumerate(frames):
        delay = start + i / rate - time.perf_counter()
        if delay > 0.0002:
            time.sleep(delay)
        bus.send(msg)


def _bare(frames: list[can.Message], rate: float | None) -> tuple[float, list[float], int]:
    channel = f"bench-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as rx, can.Bus(
        interface="virtual", channel=channel
    ) as tx:
        if rate is None:
            for msg in frames:
                tx.send(msg)
            start = time.perf_counter()
            got = 0
            while got < len(frames) and rx.recv(1.0) is not None:
                got += 1
            return got / (time.perf_counter() - start), [], len(frames) - got
        sender = threading.Thread(target=_send_paced, args=(tx, frames, rate), daemon=True)
        latencies = []
        sender.start()
        while len(latencies) < len(frames):
            msg = rx.recv(1.0)
            if msg is None:
                break
            latencies.append(time.time() - msg.timestamp)
        sender.join()
        return 0.0, latencies, len(frames) - len(latencies)


def _assembled(
    db: RigDatabase, frames: list[can.Message], rate: float | None
) -> tuple[float, list[float], int, float]:
    channel = f"bench-{uuid.uuid4().hex}"
    assembler = RigStateAssembler(db)
    probe = _Probe(assembler)
    publisher = _Publisher(assembler, 1000.0)
    with can.Bus(interface="virtual", channel=channel) as rx, can.Bus(
        interface="virtual", channel=channel
    ) as tx:
        if rate is None:
            for msg in frames:
                tx.send(msg)
        publisher.start()
        start = time.perf_counter()
        notifier = can.Notifier(rx, [probe], timeout=0.05)
        if rate is not None:
            _send_paced(tx, frames, rate)
        deadline = time.perf_counter() + 10.0
        while probe.count < len(frames) and time.perf_counter() < deadline:
            time.sleep(0.001)
        elapsed = time.perf_counter() - start
        notifier.stop()
        publisher.stop_event.set()
        publisher.join()
    throughput = probe.count / elapsed if rate is None else 0.0
    return throughput, probe.latencies, len(frames) - probe.count, publisher.rate


def _result(name: str, throughput: float, lat1: list[float], lat5: list[float], lost: int,
            *extra) -> BenchResult:
    """Build a row: latencies [s] -> median/p99 [ms] at 1 and 5 kHz."""
    ms = 1000.0
    median1 = statistics.median(lat1) * ms if lat1 else float("nan")
    median5 = statistics.median(lat5) * ms if lat5 else float("nan")
    return BenchResult(name, throughput, median1, _percentile(lat1, 0.99) * ms, median5,
                       _percentile(lat5, 0.99) * ms, lost, *extra)


def run_bench(frames: int = 20000, seconds: float = 2.0) -> list[BenchResult]:
    """Run both paths; ``frames`` for throughput, ``seconds`` [s] per latency rate."""
    db = RigDatabase()
    bulk = _frames(db, frames)
    paced_1k = _frames(db, max(1, int(1000 * seconds)))
    paced_5k = _frames(db, max(1, int(5000 * seconds)))
    thr, _, lost0 = _bare(bulk, None)
    _, lat1, lost1 = _bare(paced_1k, 1000.0)
    _, lat5, lost5 = _bare(paced_5k, 5000.0)
    bare = _result("bare python-can recv loop", thr, lat1, lat5, lost0 + lost1 + lost5)
    thr, _, lost0, _ = _assembled(db, bulk, None)
    _, lat1, lost1, snaps = _assembled(db, paced_1k, 1000.0)
    _, lat5, lost5, _ = _assembled(db, paced_5k, 5000.0)
    full = _result("Notifier + DBC decode + assembler (1 kHz snapshots)", thr, lat1, lat5,
                   lost0 + lost1 + lost5, snaps)
    return [bare, full]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures (``--json`` for machine-readable output)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20000, help="frames for throughput")
    parser.add_argument("--seconds", type=float, default=2.0, help="seconds per latency rate")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    results = run_bench(args.frames, args.seconds)
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
        return 0
    print(f"CAN receive path, python-can {can.__version__}, virtual bus, 8-byte frames")
    print(
        f"{'path':<52} {'frames/s':>10} {'1 kHz med/p99 [ms]':>20} "
        f"{'5 kHz med/p99 [ms]':>20} {'lost':>5}"
    )
    for r in results:
        print(
            f"{r.path:<52} {r.throughput:>10.0f} "
            f"{r.lat_median_1k:>9.3f}/{r.lat_p99_1k:<10.3f} "
            f"{r.lat_median_5k:>9.3f}/{r.lat_p99_5k:<10.3f} {r.lost:>5d}"
        )
    snaps = results[-1].snapshots_per_s
    print(f"RigState snapshots taken during the 1 kHz latency run: {snaps:.0f} /s (target 1000)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
