"""What one executor wake-up costs here: CPU per message of an echo node, by entities and executor.

``python -m benchmarks.wakeup_probe`` starts, one after the other, a probe node process (in a
ROS domain of its own) and a publisher process feeding it ``RigState`` at ``--rate`` [Hz]
(sensor-data QoS, as the bridge's ``rig_state``), and reads the probe's CPU time
(``utime + stime`` from ``/proc``) over ``--seconds`` after a warm-up. Probe variants:

* ``bare``: an echo node (one ``RigState`` out per input) without parameter services;
* ``params``: the same with rclpy's parameter services (the nodes' default: 7 services, the
  ``/parameter_events`` publisher);
* ``lifecycle``: a lifecycle node (as ``can_bridge``: 6 more services) echoing;
* ``timer``: no input; a no-op timer at ``--rate`` (the cost of one timer wake-up);

each with rclpy's SingleThreadedExecutor (``single``) and :class:`LeanExecutor` (``lean``).
Rows: CPU per second [core] and per message (or timer call) [ms]. Figures depend on machine
load (the CPU time of a wake-up grows when other processes evict the caches): compare rows
of one run.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time

from benchmarks.live_cpu import read_cpu

__all__ = ["main"]

VARIANTS = ("bare", "params", "lifecycle", "timer")
EXECUTORS = ("single", "lean")


def _probe_main(variant: str, executor: str, rate: float) -> int:
    """Run one probe node until SIGINT/SIGTERM."""
    from clutch_msgs.msg import RigState
    from rclpy.lifecycle import LifecycleNode
    from rclpy.node import Node

    from clutch_ros.nodes.qos import sensor_qos
    from clutch_ros.nodes.runner import run_node

    base = LifecycleNode if variant == "lifecycle" else Node

    class Probe(base):  # type: ignore[misc, valid-type]
        def __init__(self):
            super().__init__("wakeup_probe", start_parameter_services=variant != "bare")
            if variant == "timer":
                self.create_timer(1.0 / rate, lambda: None)
                return
            pub = self.create_publisher(RigState, "probe_out", sensor_qos())
            self.create_subscription(RigState, "rig_state", pub.publish, sensor_qos())

    return run_node("wakeup_probe", "wake-up probe", [], Probe, ["--executor", executor])


def _pub_main(rate: float, seconds: float) -> int:
    """Publish RigState at ``rate`` [Hz] for ``seconds`` [s] once a subscriber is there."""
    import rclpy
    from clutch_msgs.msg import RigState

    from clutch_ros.nodes.qos import sensor_qos

    rclpy.init()
    node = rclpy.create_node(f"probe_pub_{os.getpid()}")
    pub = node.create_publisher(RigState, "rig_state", sensor_qos())
    msg = RigState()
    start = time.monotonic()
    for i in range(int(seconds * rate)):
        while (wait := start + i / rate - time.monotonic()) > 0:
            time.sleep(wait)
        pub.publish(msg)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _measure(variant: str, executor: str, rate: float, seconds: float, warmup: float) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 230)),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    me = [sys.executable, "-m", "benchmarks.wakeup_probe"]
    probe = subprocess.Popen([*me, "probe", variant, executor, str(rate)], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pub = None
    try:
        if variant != "timer":
            pub = subprocess.Popen([*me, "pub", str(rate), str(warmup + seconds + 2.0)],
                                   env=env, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)
        time.sleep(warmup + 1.5)  # start-up, discovery, warm-up
        c0, t0 = read_cpu(probe.pid), time.monotonic()
        time.sleep(seconds)
        c1, t1 = read_cpu(probe.pid), time.monotonic()
    finally:
        for proc in (pub, probe):
            if proc is not None:
                proc.terminate()
                proc.wait(10)
    if c0 is None or c1 is None:
        raise RuntimeError(f"probe {variant}/{executor} exited early")
    core = (c1 - c0) / (t1 - t0)
    return {"variant": variant, "executor": executor, "cpu_core": core,
            "cpu_per_event_ms": core / rate * 1e3}


def main(argv=None) -> int:
    """Run every variant with each executor and print one row each."""
    args_in = sys.argv[1:] if argv is None else argv
    if args_in[:1] == ["probe"]:
        return _probe_main(args_in[1], args_in[2], float(args_in[3]))
    if args_in[:1] == ["pub"]:
        return _pub_main(float(args_in[1]), float(args_in[2]))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=100.0, help="messages per second [Hz]")
    parser.add_argument("--seconds", type=float, default=8.0, help="measured window [s]")
    parser.add_argument("--warmup", type=float, default=2.0, help="warm-up [s]")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--executors", default=",".join(EXECUTORS))
    args = parser.parse_args(args_in)
    print(f"{'variant':10s} {'executor':8s} {'cpu [core]':>10s} {'per event [ms]':>15s}")
    for variant in args.variants.split(","):
        for executor in args.executors.split(","):
            r = _measure(variant, executor, args.rate, args.seconds, args.warmup)
            print(f"{variant:10s} {executor:8s} {r['cpu_core']:10.3f} "
                  f"{r['cpu_per_event_ms']:15.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
