"""Benchmark of the can_bridge NODE: ``python -m benchmarks.can_bridge_node [--json]``.

Unlike :mod:`benchmarks.can_decode` (the receive path in one process), this drives the real
``can_bridge`` process over ``udp_multicast`` (a private group and port) and compares it,
in the same run, with a bare python-can receive loop in its own process:

* throughput: 8-byte rig frames (RigFast and RigSpeed, consecutive rolling counters) are sent
  at stepped rates for ``--step-seconds`` each; a receiver is lossless at a rate when it got
  every frame sent (bridge: decoded-frame count and rolling-counter drops from its
  ``/diagnostics``; bare loop: frames received), and its peak processing rate is reported
  too (the 4 MiB socket buffer absorbs a short deficit, the peak rate shows it). The node
  publishes RigState at up to ``bridge.rate`` = 1 kHz to a subscriber here while it decodes;
* latency at 1 kHz: a RigFast + RigSpeed pair every 1 ms (the simulated rig's fast frames)
  for ``--latency-seconds``; bridge: bus timestamp (the kernel receive time, the same for
  every socket on the host) -> RigState received by an rclpy subscriber in this process;
  bare loop: bus timestamp -> ``recv()`` returned. Median and 99th percentile.

``--sustained [--seconds 60] [--rate 8000]``: a full bus for a minute, the rig's own frames
plus foreign ones, with frame accounting, trigger-to-RigState latency and CPU per receiver
(:mod:`benchmarks.can_bridge_sustained`).

Each bridge mode (``--modes``: ``publish_on`` RigSpeed, the default, and ``timer``) is a
separate node process. The sender shares the machine's cores with the receivers, so the
figures are lower bounds of what the receivers can do on a quiet machine. rclpy is imported
only here, in the benchmark (the rest of :mod:`clutch_ros.canbus` stays free of ROS).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import can

from clutch_ros.canbus.bus import BusConfig, open_bus
from clutch_ros.canbus.dbc import RigDatabase

__all__ = ["ReceiverResult", "StepResult", "main", "run"]

_START, _END, _EXIT = 0x7F0, 0x7F1, 0x7F2  # control frames (not in the DBC)
_ROOT = Path(__file__).resolve().parents[1]  # the repository


@dataclass
class StepResult:
    """One throughput step: frames sent (at ``achieved`` frames/s) and received/decoded."""

    target: float
    achieved: float
    sent: int
    received: int
    counter_drops: int = 0
    #: highest rate the receiver processed frames at during the step [frames/s] (bare loop:
    #: frames / (last - first receive time); bridge: max frame_rate_hz of its 1 s reports)
    receiver_rate: float = 0.0

    @property
    def lossless(self) -> bool:
        """True when every frame sent was received (and decoded, for the bridge)."""
        return self.received == self.sent and self.counter_drops == 0


@dataclass
class ReceiverResult:
    """One receiver: throughput steps, max lossless rate [frames/s], latency [ms]."""

    name: str
    steps: list[StepResult] = field(default_factory=list)
    latency_median_ms: float = float("nan")
    latency_p99_ms: float = float("nan")
    latency_samples: int = 0

    @property
    def max_lossless(self) -> float:
        """Highest achieved rate of a lossless step (0 if none) [frames/s]."""
        return max((s.achieved for s in self.steps if s.lossless), default=0.0)


def _say(text: str) -> None:
    """Write one line to stdout and flush it (the report, or a line to the parent)."""
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


class _Sender:
    """Paced sender of pre-encoded RigFast/RigSpeed frames with consecutive counters."""

    def __init__(self, config: BusConfig) -> None:
        db = RigDatabase()
        self.bus = open_bus(config)
        self.fast = [db.make_message("RigFast", {"ActuatingPressure": 20e5, "MeasuredTorque":
                                                 300.0, "MeasuredTorqueValid": 1}, counter=i)
                     for i in range(16)]
        self.speed = [db.make_message("RigSpeed", {"InputShaftSpeed": 5.0,
                                                   "OutputShaftSpeed": 0.0}, counter=i)
                      for i in range(16)]
        self.k = 0  # frames pairs sent (counter state survives steps)

    def control(self, arbitration_id: int, value: int = 0, repeat: int = 1) -> None:
        """Send a control frame ``repeat`` times."""
        for _ in range(repeat):
            self.bus.send(can.Message(arbitration_id=arbitration_id, data=[value & 0xFF]))
            time.sleep(0.01)

    def paced(self, rate: float, seconds: float) -> tuple[int, float]:
        """Send alternating RigFast/RigSpeed at ``rate`` frames/s; return (sent, frames/s)."""
        total = max(2, int(rate * seconds)) // 2 * 2
        sent, start = 0, time.perf_counter()
        while sent < total:
            due = min(total, int((time.perf_counter() - start) * rate) + 2)
            while sent < due:
                pair = self.k % 16
                self.bus.send(self.fast[pair] if sent % 2 == 0 else self.speed[pair])
                if sent % 2:
                    self.k += 1
                sent += 1
            time.sleep(0.0005)
        return sent, sent / (time.perf_counter() - start)

    def pairs_1khz(self, seconds: float) -> int:
        """Send one RigFast + RigSpeed pair every 1 ms for ``seconds``; return pairs sent."""
        n = int(seconds * 1000)
        start = time.perf_counter()
        for i in range(n):
            delay = start + i * 0.001 - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            pair = self.k % 16
            self.bus.send(self.fast[pair])
            self.bus.send(self.speed[pair])
            self.k += 1
        return n


# -- the bare python-can receive loop (child process) ---------------------------------------

def _bare_receiver(group: str, port: int) -> int:
    """Child process: count frames per step, record latencies; print one JSON line per step."""
    bus = open_bus(BusConfig(interface="udp_multicast", channel=group, extra={"port": port}))
    _say("ready")
    step, count, latencies, done, first, last = None, 0, [], set(), 0.0, 0.0
    while True:
        msg = bus.recv(1.0)
        if msg is None:
            continue
        now = time.time()
        ident = msg.arbitration_id
        if ident == _START:
            step, count, latencies = msg.data[0], 0, []
        elif ident == _END:
            if msg.data[0] not in done:
                done.add(msg.data[0])
                _say(json.dumps({"step": msg.data[0], "received": count,
                                 "rate": count / (last - first) if last > first else 0.0,
                                 "latencies": latencies}))
            step = None
        elif ident == _EXIT:
            break
        elif step is not None:
            first = now if count == 0 else first
            count, last = count + 1, now
            latencies.append(now - msg.timestamp)
    bus.shutdown()
    return 0


class _Bare:
    def __init__(self, group: str, port: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.can_bridge_node", "--bare-receiver", group,
             str(port)],
            stdout=subprocess.PIPE, text=True, cwd=_ROOT)
        if self.proc.stdout.readline().strip() != "ready":
            raise RuntimeError("bare receiver did not start")

    def result(self) -> dict:
        return json.loads(self.proc.stdout.readline())


# -- the bridge node (child process) and an rclpy subscriber here ---------------------------

class _Ros:
    """An rclpy context in this process: RigState latencies and the bridge's diagnostics."""

    def __init__(self) -> None:
        import rclpy
        from clutch_msgs.msg import RigState
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        from clutch_ros.nodes.qos import sensor_qos

        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("node_bench", context=self.context)
        self.latencies: list[float] | None = None
        self.states = 0
        self.diag: list[tuple[float, dict]] = []
        self.node.create_subscription(RigState, "rig_state", self._on_state, sensor_qos())
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_state(self, msg) -> None:
        now = time.time()
        self.states += 1
        if self.latencies is not None:
            self.latencies.append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))

    def _on_diag(self, msg) -> None:
        for status in msg.status:
            if status.name.endswith("can_bridge"):
                self.diag.append((time.monotonic(), {kv.key: kv.value for kv in status.values}))

    def counts_after(self, t: float, timeout: float = 15.0) -> tuple[int, int]:
        """Return (decoded_frames, dropped_frames) of the 2nd report after monotonic ``t``."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            later = [d for when, d in self.diag if when > t]
            if len(later) >= 2:
                return int(later[1]["decoded_frames"]), int(later[1]["dropped_frames"])
            time.sleep(0.05)
        raise RuntimeError("no diagnostics from can_bridge")

    def max_rate(self, since: float) -> float:
        """Return the highest frame_rate_hz reported after monotonic ``since`` [frames/s]."""
        return max((float(d["frame_rate_hz"]) for when, d in self.diag if when > since),
                   default=0.0)

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(5.0)
        self.node.destroy_node()
        import rclpy

        rclpy.try_shutdown(context=self.context)


def _bridge(group: str, port: int, mode: str, env: dict, log: Path) -> subprocess.Popen:
    params = {"can.interface": "udp_multicast", "can.channel": group, "can.port": port,
              "bridge.rate": 1000.0, "bridge.publish_on": "RigSpeed" if mode == "trigger"
              else "", "pump.watchdog_timeout": 60.0}
    args = [a for k, v in params.items() for a in ("-p", f"{k}:={v}" if v != "" else f"{k}:=''")]
    with open(log, "w") as out:
        return subprocess.Popen([sys.executable, "-m", "clutch_ros.nodes.can_bridge",
                                 "--ros-args", *args], env=env, stdout=out,
                                stderr=subprocess.STDOUT, cwd=_ROOT, start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    import signal

    for sig, wait in ((signal.SIGINT, 10.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        proc.send_signal(sig)
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            continue


# -- the run --------------------------------------------------------------------------------

def _measure_bare(sender: _Sender, group: str, port: int, rates, step_s, lat_s):
    result = ReceiverResult("bare python-can recv loop")
    bare = _Bare(group, port)
    try:
        time.sleep(0.3)
        for i, rate in enumerate(rates):
            sender.control(_START, i)
            sent, achieved = sender.paced(rate, step_s)
            time.sleep(0.5)
            sender.control(_END, i, repeat=3)
            got = bare.result()
            result.steps.append(StepResult(rate, achieved, sent, got["received"],
                                           receiver_rate=got["rate"]))
        sender.control(_START, 255)
        sender.pairs_1khz(lat_s)
        time.sleep(0.3)
        sender.control(_END, 255, repeat=3)
        lat = bare.result()["latencies"]
        result.latency_median_ms = statistics.median(lat) * 1e3
        result.latency_p99_ms = _percentile(lat, 0.99) * 1e3
        result.latency_samples = len(lat)
    finally:
        sender.control(_EXIT, 0, repeat=3)
        try:
            bare.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            bare.proc.kill()
    return result


def _measure_bridge(sender, ros, group, port, mode, rates, step_s, lat_s, env, log_dir):
    name = ("can_bridge node, publish_on RigSpeed" if mode == "trigger"
            else "can_bridge node, 1 kHz timer")
    result = ReceiverResult(name)
    proc = _bridge(group, port, mode, env, log_dir / f"can_bridge_{mode}.log")
    try:
        end = time.monotonic() + 60.0
        while not ros.diag or ros.node.count_publishers("rig_state") == 0:
            if proc.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"can_bridge did not start (log in {log_dir})")
            time.sleep(0.1)
        ros.diag.clear()
        states = ros.states
        while ros.states == states and time.monotonic() < end:  # warm up: RigState flows
            sender.pairs_1khz(0.2)
        time.sleep(1.0)
        decoded, dropped = ros.counts_after(time.monotonic())
        for rate in rates:
            start = time.monotonic()
            sent, achieved = sender.paced(rate, step_s)
            d2, x2 = ros.counts_after(time.monotonic() + 0.5)
            result.steps.append(StepResult(rate, achieved, sent, d2 - decoded, x2 - dropped,
                                           ros.max_rate(start)))
            decoded, dropped = d2, x2
        ros.latencies = []
        sender.pairs_1khz(lat_s)
        time.sleep(0.5)
        lat, ros.latencies = ros.latencies, None
        result.latency_median_ms = statistics.median(lat) * 1e3 if lat else float("nan")
        result.latency_p99_ms = _percentile(lat, 0.99) * 1e3
        result.latency_samples = len(lat)
    finally:
        _stop(proc)
    return result


def private_run(log_dir: Path | None, prefix: str) -> tuple[str, int, dict, Path]:
    """Return a private multicast group, port, child environment and log directory.

    This process joins the same ROS domain (localhost discovery), so its rclpy subscribers
    see the children's topics.
    """
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(20000, 60000)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", str(random.randint(120, 200))))
    env["PYTHONPATH"] = str(_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    log_dir = log_dir or Path("/tmp") / f"{prefix}_{os.getpid()}"
    log_dir.mkdir(parents=True, exist_ok=True)
    return group, port, env, log_dir


def run(rates=(1000, 2000, 5000, 10000, 20000, 30000), step_s: float = 3.0, lat_s: float = 5.0,
        modes=("trigger", "timer"), log_dir: Path | None = None) -> tuple[str, list]:
    """Run the benchmark; return ``(bus description, [ReceiverResult, ...])``."""
    group, port, env, log_dir = private_run(log_dir, "clutch_node_bench")
    sender = _Sender(BusConfig(interface="udp_multicast", channel=group, extra={"port": port}))
    results = [_measure_bare(sender, group, port, rates, step_s, lat_s)]
    if modes:
        ros = _Ros()
        try:
            for mode in modes:
                results.append(_measure_bridge(sender, ros, group, port, mode, rates, step_s,
                                               lat_s, env, log_dir))
        finally:
            ros.close()
    sender.bus.shutdown()
    return f"udp_multicast {group}:{port}", results


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures (``--json`` for machine-readable output)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--bare-receiver"]:
        return _bare_receiver(argv[1], int(argv[2]))
    if "--sustained" in argv:  # a full bus for a minute: its own module
        from benchmarks.can_bridge_sustained import main as sustained

        return sustained(argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="1000,2000,5000,10000,20000,30000",
                        help="throughput steps [frames/s], comma separated")
    parser.add_argument("--step-seconds", type=float, default=3.0)
    parser.add_argument("--latency-seconds", type=float, default=5.0)
    parser.add_argument("--modes", default="trigger,timer",
                        help="bridge modes: trigger (publish_on RigSpeed), timer; empty: none")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",") if r]
    modes = [m for m in args.modes.split(",") if m]
    bus, results = run(rates, args.step_seconds, args.latency_seconds, modes)
    if args.json:
        _say(json.dumps([{**asdict(r), "max_lossless": r.max_lossless} for r in results],
                         indent=2))
        return 0
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    _say(f"can_bridge node benchmark: python-can {can.__version__}, {bus}, 8-byte "
         f"RigFast/RigSpeed frames, {os.cpu_count()} CPUs shared with the sender "
         f"(load average {load})")
    _say(f"{'receiver':<38} {'lossless up to':>15} {'1 kHz latency median / p99':>28}")
    for r in results:
        _say(f"{r.name:<38} {r.max_lossless:>9.0f} fr/s {r.latency_median_ms:>12.3f} ms / "
              f"{r.latency_p99_ms:.3f} ms  (n={r.latency_samples})")
    _say("throughput steps (sent frames/s: received/sent frames, receiver's peak frames/s):")
    for r in results:
        steps = "; ".join(f"{s.achieved:.0f}: {s.received}/{s.sent} @{s.receiver_rate:.0f}"
                          f"{f' drops {s.counter_drops}' if s.counter_drops else ''}"
                          for s in r.steps)
        _say(f"  {r.name}: {steps}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
