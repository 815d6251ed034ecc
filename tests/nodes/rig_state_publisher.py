"""A real publisher process for recorder tests: RigState at a fixed rate until stopped.

``python -m tests.nodes.rig_state_publisher --rate 200 --log published.json`` publishes
``rig_state`` (reliable, keep last 50: what can_bridge offers) with message ``i`` carrying
``i`` in ``measured_torque`` and its publish time (wall clock, ``time.time()``) as header
stamp. On SIGINT/SIGTERM it writes ``{"t": [publish time of message i, ...]}`` [s] to
``--log`` and exits 0. The test that kills a recorder compares what was recovered with it.
"""

from __future__ import annotations

import argparse
import json
import signal
import time
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rate", type=float, default=200.0, help="[Hz]")
    parser.add_argument("--log", required=True, help="JSON file of the publish times")
    args = parser.parse_args()

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    from tests.nodes.rclpy_harness import rig_state

    stop = []
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    node = rclpy.create_node("rig_state_publisher")
    pub = node.create_publisher(rig_state(0.0).__class__, "rig_state",
                                QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    times: list[float] = []
    period, start = 1.0 / args.rate, time.monotonic()
    while not stop:
        i = len(times)
        delay = start + i * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.time()
        msg = rig_state(now)
        msg.measured_torque = float(i)
        pub.publish(msg)
        times.append(now)
    tmp = Path(args.log + ".tmp")
    tmp.write_text(json.dumps({"t": times}))
    tmp.replace(args.log)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
