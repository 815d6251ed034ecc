"""Benchmark of the estimator node against a bare rclpy echo node, over DDS, same messages.

``python -m benchmarks.estimator_node`` starts, one after the other, node processes that turn
each RigState into one output message, each with every executor of ``--executors`` (default
``lean,single``: the nodes' default :class:`~clutch_ros.nodes.lean_executor.LeanExecutor` and
rclpy's SingleThreadedExecutor; ``events`` adds rclpy.experimental.EventsExecutor):

* ``echo``: a bare rclpy node republishing every RigState as it came (the baseline: the hop
  cost of rclpy and DDS without the estimator's work), best-effort output; and once, with the
  first executor, with a reliable output like the estimator's ClutchEstimate (reliable
  publishers keep a history and heartbeat; that row shows the transport's share);
* ``estimator``: the estimator node (flexiforce_8 preset).

For each it measures, with a publisher process (``bench pub``) feeding the node under test
and this process receiving its output in a thread of its own:

* for each input rate of ``--rates`` (``--seconds`` each, sensor-data QoS as on the rig): the
  fraction of inputs that came out, and the latency (output receive time minus the input's
  publish time, carried in its header stamp), median and p99 [ms];
* the sustained rate: the highest input rate with >= 99 % of the inputs out.

The publisher and the receiver are the measuring instrument, so they are as lean as rclpy
allows, and their share is in every row alike: no parameter services, no rosout; the
publisher stamps each message just before ``publish`` and never spins; the receiver
subscribes best effort (as the controller takes ``clutch_estimate``), raw (no message is
deserialised: the stamp and frame_id are read from the CDR bytes after the run), spins a
LeanExecutor in a thread, and collects no garbage while it measures. DDS: the wheels' only
rmw, Fast DDS (``rmw_fastrtps_cpp``), with its default synchronous publication (``publish``
writes in the caller's thread) and shared-memory transport between local processes.

Targets: the estimator sustains >= 2 kHz and reaches >= 70 % of the echo node's throughput;
its p99 latency at 1 kHz is below 1 ms. Figures vary with machine load; run it on a quiet
machine. ``--realtime PRIORITY`` runs every process of the measurement (publisher, node under
test, receiver) at SCHED_FIFO with locked memory, through the nodes' own ``rt.*`` parameters
(README.md, On the real rig) -- the setting a rig PC that allows it would use; where the OS
refuses, the rows say so and the run goes on at the normal policy.
"""

from __future__ import annotations

import argparse
import gc
import os
import random
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from benchmarks.machine_load import MachineLoad

__all__ = ["main"]

ECHO = "echo"
ECHO_RELIABLE = "echo-reliable"
PUB = "pub"
EXECUTORS = ("lean", "single", "events")
WARMUP_MAX_S = 60.0  # [s] the publisher's warm-up ends at the latest after this
READY_AFTER = 50  # outputs received before the measured steps start


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
    priority, ready = int(argv[2]), argv[3]
    rclpy.init(args=[sys.argv[0], *argv[4:]])
    node = rclpy.create_node(f"bench_pub_{os.getpid()}", start_parameter_services=False,
                             enable_rosout=False)  # the instrument: nothing it does not need
    realtime(priority)
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
    start = time.monotonic()
    # warm-up: 3 s, and until the receiver has the node's output (file ``ready`` exists)
    while time.monotonic() < start + 3.0 or (not os.path.exists(ready)
                                             and time.monotonic() < start + WARMUP_MAX_S):
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


def realtime(priority: int) -> str:
    """SCHED_FIFO at ``priority`` with locked memory for this process (0: leave it); the outcome."""
    if not priority:
        return "normal policy"
    from clutch_ros.nodes.realtime import RealtimeSettings, apply_realtime

    report = apply_realtime(RealtimeSettings("fifo", priority, lock_memory=True))
    return report.message()


def _stamp_and_frame(raw: bytes) -> tuple[float, str]:
    """Header stamp [s] and frame_id of a serialised message that starts with a Header.

    CDR: a 4-byte encapsulation header (byte 1: 1 little endian, 0 big endian), then
    ``int32 sec``, ``uint32 nanosec``, ``uint32`` string length (with its NUL), the chars.
    """
    order = "<" if raw[1] & 1 else ">"
    sec, nanosec, length = struct.unpack_from(order + "iII", raw, 4)
    return sec + nanosec * 1e-9, raw[16:16 + length - 1].decode()


def _measure(cmd: list[str], out_topic: str, out_type, rates: list[float], seconds: float,
             priority: int = 0) -> dict:
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from clutch_ros.nodes.lean_executor import LeanExecutor

    domain = str(random.randint(150, 230))
    os.environ.update(ROS_DOMAIN_ID=domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    got: list[tuple[float, bytes]] = []  # (receive time [s], serialised message)
    record = got.append

    def on_output(raw: bytes) -> None:
        record((time.time(), raw))

    rclpy.init()
    node = rclpy.create_node(f"bench_sink_{os.getpid()}", start_parameter_services=False,
                             enable_rosout=False)
    # best effort (as the controller reads clutch_estimate), deep enough never to overwrite
    qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                     depth=10000)
    node.create_subscription(out_type, out_topic, on_output, qos, raw=True)
    executor = LeanExecutor()
    executor.add_node(node)
    sink_rt = realtime(priority)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    under_test = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
    ready = tempfile.NamedTemporaryFile(prefix="bench_ready_", delete=False).name
    os.unlink(ready)  # created once output arrives: the publisher's warm-up then ends
    publisher = subprocess.Popen([sys.executable, "-m", "benchmarks.estimator_node", PUB,
                                  str(seconds), ",".join(f"{r:.0f}" for r in rates),
                                  str(priority), ready], env=env)
    gc.collect()
    gc.freeze()
    gc.disable()  # no collection pauses the receiver while it measures
    try:
        deadline = time.monotonic() + WARMUP_MAX_S + 60.0
        while len(got) < READY_AFTER and publisher.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        open(ready, "w").close()
        publisher.wait(timeout=WARMUP_MAX_S + 120 + (seconds + 1.0) * len(rates))
        time.sleep(1.0)
    finally:
        gc.enable()
        if os.path.exists(ready):
            os.unlink(ready)
        for proc in (publisher, under_test):
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        executor.shutdown()  # wakes the spin thread, which releases its handles and ends
        spin.join(5.0)
        node.destroy_node()
        rclpy.try_shutdown()
    received: dict[str, list[tuple[float, float]]] = {"warmup": []}
    for when, raw in got:
        stamp, frame = _stamp_and_frame(raw)
        received.setdefault(frame, []).append((when, stamp))
    if not received["warmup"]:
        raise RuntimeError(f"no output from {' '.join(cmd)}")
    steps = {}
    for rate in rates:
        step = received.get(f"{rate:.0f}", [])
        lat = np.array([r - s for r, s in step]) * 1e3
        steps[rate] = {"delivered": len(step) / (seconds * rate),
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
    parser.add_argument("--executors", default="lean,single",
                        help="executors of the echo and estimator rows, comma separated "
                             "(lean, single, events)")
    args = parser.parse_args(argv)
    if not 0 <= args.realtime <= 99:
        parser.error(f"--realtime: a priority 1..99 (or 0 for off), got {args.realtime}")
    executors = args.executors.split(",")
    if not executors or set(executors) - set(EXECUTORS):
        parser.error(f"--executors: some of {', '.join(EXECUTORS)}, got {args.executors!r}")
    rt_args = (["-p", "rt.policy:=fifo", "-p", f"rt.priority:={args.realtime}",
                "-p", "rt.lock_memory:=true"] if args.realtime else [])
    from clutch_msgs.msg import ClutchEstimate, RigState

    from clutch_ros.config.presets import preset_path

    py = sys.executable
    preset = str(preset_path("flexiforce_8"))
    est_args = ["--ros-args", "--params-file", preset, "-p", "estimator.max_sample_age:=0.0",
                *rt_args]
    me = [py, "-m", "benchmarks.estimator_node"]
    rows = []  # name, command, output topic and type
    for i, ex in enumerate(executors):
        rows.append((f"bare rclpy echo ({ex})", [*me, ECHO, "--executor", ex, "--ros-args",
                                                 *rt_args], "bench_out", RigState))
        if i == 0:
            rows.append((f"echo, reliable output ({ex})", [*me, ECHO_RELIABLE, "--executor", ex,
                                                           "--ros-args", *rt_args],
                         "bench_out", RigState))
    rows += [(f"estimator ({ex})", [py, "-m", "clutch_ros.nodes.estimator", "--executor", ex,
                                    *est_args], "clutch_estimate", ClutchEstimate)
             for ex in executors]
    rates = [float(r) for r in args.rates.split(",")]
    results = {}
    load = MachineLoad()
    load.start()
    print(f"{'node':38s} {'sustained':>10s}  per input rate: delivered, median/p99 latency [ms]")
    for name, cmd, topic, typ in rows:
        try:
            r = _measure(cmd, topic, typ, rates, args.seconds, args.realtime)
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
    print(load.stop().line())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
