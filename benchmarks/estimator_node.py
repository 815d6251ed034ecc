"""Benchmark of the estimator node against a bare rclpy echo node, over DDS, same messages.

``python -m benchmarks.estimator_node`` starts, one after the other, node processes that turn
each RigState into one output message:

* ``echo``: a bare rclpy node republishing every RigState as it came (the baseline), with a
  best-effort output, and again with a reliable output like the estimator's ClutchEstimate
  (reliable delivery repairs losses by retransmission, which shows in the latency tail, so
  that row separates the transport's share of the estimator's p99 from the node's own);
* ``estimator``: the estimator node (flexiforce_8 preset), with the SingleThreadedExecutor and
  with ``rclpy.experimental.EventsExecutor``.

For each it measures, with a publisher process (``bench pub``) feeding the node under test
and this process receiving its output in a thread of its own (so the probe is never the
bottleneck; its overhead is in every row alike):

* for each input rate of ``--rates`` (``--seconds`` each, sensor-data QoS as on the rig): the
  fraction of inputs that came out, and the latency (output receive time minus the input's
  publish time, carried in its header stamp), median and p99 [ms];
* the sustained rate: the highest input rate with >= 99 % of the inputs out.

Targets: the estimator sustains >= 2 kHz and reaches >= 70 % of the echo node's throughput;
its p99 latency at 1 kHz is below 1 ms. Figures vary with machine load; run it on a quiet
machine. ``--realtime PRIORITY`` runs every process of the measurement (publisher, node under
test, receiver) at SCHED_FIFO with locked memory, through the nodes' own ``rt.*`` parameters
(README.md, On the real rig) -- the setting a rig PC that allows it would use; where the OS
refuses, the rows say so and the run goes on at the normal policy.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import threading
import time

import numpy as np

__all__ = ["main"]

ECHO = "echo"
ECHO_RELIABLE = "echo-reliable"
PUB = "pub"


def _echo_main(reliable: bool) -> int:
    from clutch_msgs.msg import RigState
    from rclpy.node import Node

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos
    from clutch_ros.nodes.runner import run_node

    class EchoNode(Node):
        """Republish every RigState unchanged (best effort, or reliable as the estimator)."""

        def __init__(self):
            super().__init__("bench_echo")
            out_qos = reliable_qos() if reliable else sensor_qos()
            pub = self.create_publisher(RigState, "bench_out", out_qos)
            self.create_subscription(RigState, "rig_state", pub.publish, sensor_qos())

    return run_node("bench_echo", "bare echo node", [], EchoNode, sys.argv[2:])


def _pub_main(argv: list[str]) -> int:
    """Publish ``seconds`` at each rate of a comma-separated list (frame_id = the rate)."""
    import rclpy
    from clutch_msgs.msg import RigState

    from clutch_ros.nodes.qos import sensor_qos

    seconds, rates = float(argv[0]), [float(r) for r in argv[1].split(",")]
    priority = int(argv[2])
    rclpy.init(args=[sys.argv[0], *argv[3:]])
    node = rclpy.create_node(f"bench_pub_{os.getpid()}")
    _realtime(priority)
    pub = node.create_publisher(RigState, "rig_state", sensor_qos())
    msg = RigState()
    msg.actuating_pressure, msg.lamella_temperature, msg.slip_speed = 20e5, 40.0, 1.047
    msg.measured_torque, msg.has_measured_torque = 600.0, True

    def send(frame_id: str) -> None:
        now = time.time()
        msg.header.stamp.sec = int(now)
        msg.header.stamp.nanosec = int((now - int(now)) * 1e9)
        msg.header.frame_id = frame_id
        pub.publish(msg)

    while pub.get_subscription_count() < 1:  # the node under test
        time.sleep(0.05)
    end = time.monotonic() + 3.0
    while time.monotonic() < end:  # warm-up: discovery of the output side settles
        send("warmup")
        time.sleep(0.01)
    for rate in rates:  # frame_id names the step: "1000", "2000", ...
        start, period = time.monotonic(), 1.0 / rate
        for i in range(int(seconds * rate)):
            while (wait := start + i * period - time.monotonic()) > 0:
                if wait > 2e-4:
                    time.sleep(wait - 1e-4)
            send(f"{rate:.0f}")
        time.sleep(1.0)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _realtime(priority: int) -> str:
    """SCHED_FIFO at ``priority`` with locked memory for this process (0: leave it); the outcome."""
    if not priority:
        return "normal policy"
    from clutch_ros.nodes.realtime import RealtimeSettings, apply_realtime

    report = apply_realtime(RealtimeSettings("fifo", priority, lock_memory=True))
    return report.message()


def _measure(cmd: list[str], out_topic: str, out_type, reliable: bool, rates: list[float],
             seconds: float, priority: int = 0) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    domain = str(random.randint(150, 230))
    os.environ.update(ROS_DOMAIN_ID=domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    received: dict[str, list[tuple[float, float]]] = {"warmup": []}

    def on_output(msg) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        received.setdefault(msg.header.frame_id, []).append((time.time(), stamp))

    rclpy.init()
    node = rclpy.create_node(f"bench_sink_{os.getpid()}")
    qos = reliable_qos(depth=1000) if reliable else sensor_qos()
    node.create_subscription(out_type, out_topic, on_output, qos)
    # SingleThreadedExecutor: EventsExecutor spun in a background thread was seen to hang
    # here (busy, no callbacks); the main thread only waits, so the GIL is free for it.
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    sink_rt = _realtime(priority)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    under_test = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
    publisher = subprocess.Popen([sys.executable, "-m", "benchmarks.estimator_node", PUB,
                                  str(seconds), ",".join(f"{r:.0f}" for r in rates),
                                  str(priority)], env=env)
    try:
        publisher.wait(timeout=120 + (seconds + 1.0) * len(rates))
        time.sleep(1.0)
    finally:
        for proc in (publisher, under_test):
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if not received["warmup"]:
        raise RuntimeError(f"no output from {' '.join(cmd)}")
    steps = {}
    for rate in rates:
        got = received.get(f"{rate:.0f}", [])
        lat = np.array([r - s for r, s in got]) * 1e3
        steps[rate] = {"delivered": len(got) / (seconds * rate),
                       "lat_median_ms": float(np.median(lat)) if lat.size else float("nan"),
                       "lat_p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan")}
    lossless = [r for r in rates if steps[r]["delivered"] >= 0.99]
    return {"steps": steps, "sustained_hz": max(lossless) if lossless else 0.0,
            "receiver_realtime": sink_rt}


def main(argv=None) -> int:
    """Run the benchmark and print one row per node under test."""
    if argv is None and len(sys.argv) > 1 and sys.argv[1] in (ECHO, ECHO_RELIABLE):
        return _echo_main(sys.argv[1] == ECHO_RELIABLE)
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == PUB:
        return _pub_main(sys.argv[2:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rates", default="1000,2000,2500,3000,3500,4000",
                        help="input rates to step through [Hz], comma separated")
    parser.add_argument("--seconds", type=float, default=3.0, help="time at each rate [s]")
    parser.add_argument("--realtime", type=int, default=0, metavar="PRIORITY",
                        help="run publisher, node under test and receiver at SCHED_FIFO of this "
                             "priority (1..99) with locked memory; 0 (default): normal policy")
    args = parser.parse_args(argv)
    if not 0 <= args.realtime <= 99:
        parser.error(f"--realtime: a priority 1..99 (or 0 for off), got {args.realtime}")
    rt_args = (["-p", "rt.policy:=fifo", "-p", f"rt.priority:={args.realtime}",
                "-p", "rt.lock_memory:=true"] if args.realtime else [])
    from clutch_msgs.msg import ClutchEstimate, RigState

    from clutch_ros.config.presets import preset_path

    py = sys.executable
    preset = str(preset_path("flexiforce_8"))
    est = ["-m", "clutch_ros.nodes.estimator"]
    est_args = ["--ros-args", "--params-file", preset, "-p", "estimator.max_sample_age:=0.0",
                *rt_args]
    echo = [py, "-m", "benchmarks.estimator_node"]
    rows = [  # name, command, output topic and type, output reliable
        ("bare rclpy echo (single)", [*echo, ECHO, "--ros-args", *rt_args], "bench_out",
         RigState, False),
        ("echo, reliable output", [*echo, ECHO_RELIABLE, "--ros-args", *rt_args], "bench_out",
         RigState, True),
        ("estimator (SingleThreadedExecutor)", [py, *est, "--executor", "single", *est_args],
         "clutch_estimate", ClutchEstimate, True),
        ("estimator (EventsExecutor)", [py, *est, "--executor", "events", *est_args],
         "clutch_estimate", ClutchEstimate, True),
    ]
    rates = [float(r) for r in args.rates.split(",")]
    results = {}
    print(f"{'node':38s} {'sustained':>10s}  per input rate: delivered, median/p99 latency [ms]")
    for name, cmd, topic, typ, reliable in rows:
        try:
            r = _measure(cmd, topic, typ, reliable, rates, args.seconds, args.realtime)
        except RuntimeError as err:
            print(f"{name:38s} {'failed':>10s}  {err}", flush=True)
            continue
        results[name] = r
        cells = "; ".join(f"{rate:.0f} Hz: {v['delivered']:.3f}, {v['lat_median_ms']:.2f}/"
                          f"{v['lat_p99_ms']:.2f}" for rate, v in r["steps"].items())
        print(f"{name:38s} {r['sustained_hz']:8.0f} Hz  {cells}", flush=True)
    if results:
        print("receiver: " + next(iter(results.values()))["receiver_realtime"])
    echo = results.get(rows[0][0], {}).get("sustained_hz", 0.0)
    for name in list(results)[1:]:
        share = results[name]["sustained_hz"] / echo if echo else float("nan")
        print(f"{name}: sustains {results[name]['sustained_hz']:.0f} Hz lossless, "
              f"{share:.2f} of the echo node's {echo:.0f} Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
