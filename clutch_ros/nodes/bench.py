"""Benchmark of the estimator node against a bare rclpy echo node, over DDS, same messages.

``python -m clutch_ros.nodes.bench`` starts, one after the other, node processes that turn
each RigState into one output message:

* ``echo``: a bare rclpy node republishing every RigState as it came (the baseline);
* ``estimator``: the estimator node (flexiforce_8 preset), with the SingleThreadedExecutor and
  with ``rclpy.experimental.EventsExecutor``.

For each it measures, from this process (publisher and subscriber on one node, spun in a
background thread; the benchmark's own overhead is in every row alike):

* throughput: a flood of ``--flood`` RigState messages published as fast as possible (sensor
  QoS, as on the rig); outputs per second between the first and last output, and the
  fraction delivered;
* latency at 1 kHz for ``--seconds``: output receive time minus the input's publish time
  (carried in its header stamp), median and p99 [ms], and outputs per second.

Targets (issue 5): the estimator sustains >= 2 kHz and reaches >= 70 % of the echo node's
throughput. Figures vary with machine load; run it on a quiet machine.
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


def _echo_main() -> int:
    from clutch_msgs.msg import RigState
    from rclpy.node import Node

    from clutch_ros.nodes.common import run_node, sensor_qos

    class EchoNode(Node):
        """Republish every RigState unchanged."""

        def __init__(self):
            super().__init__("bench_echo")
            pub = self.create_publisher(RigState, "bench_out", sensor_qos())
            self.create_subscription(RigState, "rig_state", pub.publish, sensor_qos())

    return run_node("bench_echo", "bare echo node", [], EchoNode, sys.argv[2:])


class _Probe:
    """Publisher of RigState and subscriber of the node's output, spun in a thread."""

    def __init__(self, out_topic: str, out_type):
        import rclpy
        from clutch_msgs.msg import RigState
        from rclpy.executors import SingleThreadedExecutor

        from clutch_ros.nodes.common import reliable_qos, sensor_qos

        rclpy.init()
        self.node = rclpy.create_node(f"bench_probe_{os.getpid()}")
        qos = sensor_qos() if out_type is RigState else reliable_qos()
        self.received: list[tuple[float, float]] = []  # (receive time, input stamp) [s]
        self.node.create_subscription(out_type, out_topic, self._on_output, qos)
        self.pub = self.node.create_publisher(RigState, "rig_state", sensor_qos())
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self.executor.spin, daemon=True)
        self._spin.start()
        self.msg = RigState()
        self.msg.actuating_pressure = 20e5
        self.msg.lamella_temperature = 40.0
        self.msg.slip_speed = 1.047
        self.msg.measured_torque = 600.0
        self.msg.has_measured_torque = True

    def _on_output(self, msg) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.received.append((time.time(), stamp))

    def publish(self) -> None:
        now = time.time()
        self.msg.header.stamp.sec = int(now)
        self.msg.header.stamp.nanosec = int((now - int(now)) * 1e9)
        self.pub.publish(self.msg)

    def wait_connected(self, timeout: float = 30.0) -> None:
        end = time.monotonic() + timeout
        while self.pub.get_subscription_count() == 0 or not self.received:
            if time.monotonic() > end:
                raise RuntimeError("node under test did not connect")
            self.publish()
            time.sleep(0.05)
        time.sleep(0.5)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def _settle(probe: _Probe, quiet: float = 1.0) -> None:
    last, since = -1, time.monotonic()
    while time.monotonic() - since < quiet:
        if len(probe.received) != last:
            last, since = len(probe.received), time.monotonic()
        time.sleep(0.05)


def _measure(cmd: list[str], out_topic: str, out_type, flood: int, seconds: float) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 230)),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    probe = _Probe(out_topic, out_type)
    try:
        probe.wait_connected()
        # Latency at 1 kHz.
        probe.received.clear()
        period, start = 1e-3, time.monotonic()
        n = int(seconds / period)
        for i in range(n):
            while time.monotonic() < start + i * period:
                pass
            probe.publish()
        _settle(probe)
        lat = np.array([r - s for r, s in probe.received]) * 1e3
        rate_1k = len(probe.received) / seconds
        # Throughput: flood.
        probe.received.clear()
        for _ in range(flood):
            probe.publish()
        _settle(probe)
        times = np.array([r for r, _ in probe.received])
        span = times[-1] - times[0] if len(times) > 1 else float("nan")
        return {"throughput_hz": (len(times) - 1) / span if span > 0 else float("nan"),
                "delivered": len(times) / flood, "lat_median_ms": float(np.median(lat)),
                "lat_p99_ms": float(np.percentile(lat, 99)), "rate_at_1khz_hz": rate_1k}
    finally:
        probe.close()
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def main(argv=None) -> int:
    """Run the benchmark and print one row per node under test."""
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == ECHO:
        return _echo_main()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flood", type=int, default=20000, help="messages in the flood")
    parser.add_argument("--seconds", type=float, default=5.0, help="1 kHz latency run [s]")
    args = parser.parse_args(argv)
    from clutch_msgs.msg import ClutchEstimate, RigState

    from clutch_ros.presets import preset_path

    py = sys.executable
    preset = str(preset_path("flexiforce_8"))
    est = ["-m", "clutch_ros.nodes.estimator"]
    est_args = ["--ros-args", "--params-file", preset, "-p", "estimator.max_sample_age:=0.0"]
    rows = [
        ("bare rclpy echo (single)", [py, "-m", "clutch_ros.nodes.bench", ECHO, "--ros-args",
                                      "-r", "__node:=bench_echo"], "bench_out", RigState),
        ("estimator (SingleThreadedExecutor)", [py, *est, "--executor", "single", *est_args],
         "clutch_estimate", ClutchEstimate),
        ("estimator (EventsExecutor)", [py, *est, "--executor", "events", *est_args],
         "clutch_estimate", ClutchEstimate),
    ]
    results = {}
    print(f"{'node':38s} {'flood out/s':>12s} {'delivered':>9s} {'1 kHz out/s':>11s} "
          f"{'median ms':>9s} {'p99 ms':>8s}")
    for name, cmd, topic, typ in rows:
        r = _measure(cmd, topic, typ, args.flood, args.seconds)
        results[name] = r
        print(f"{name:38s} {r['throughput_hz']:12.0f} {r['delivered']:9.3f} "
              f"{r['rate_at_1khz_hz']:11.0f} {r['lat_median_ms']:9.3f} {r['lat_p99_ms']:8.3f}",
              flush=True)
    echo = results[rows[0][0]]["throughput_hz"]
    for name, _, _, _ in rows[1:]:
        print(f"{name}: {results[name]['throughput_hz'] / echo:.2f} of the echo node's "
              "throughput")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
