"""The chain's messages without its work: the floor of its CPU budget in bare rclpy.

``python -m benchmarks.chain_skeleton ROLE [--rig-rate HZ] [--ros-args ...]`` runs one of
three bare rclpy nodes that exchange the live chain's messages -- the same types, QoS
(``clutch_ros.interfaces``), rates and mechanisms as the nodes -- and do nothing else:

* ``bridge``: publishes ``rig_state`` from a thread at ``--rig-rate`` [Hz] (the can_bridge
  publishes it from its receive thread, on the trigger frame), and on a cycle thread every
  ``PUMP_PERIOD`` takes the queued ``pressure_command`` messages (polled, raw: as the bridge's
  pump cycle) and publishes a ``pump_request`` report;
* ``estimator``: one ``clutch_estimate`` per ``rig_state``, from a raw subscription's
  callback in the nodes' executor (``run_node``), as the estimator;
* ``controller``: on a cycle thread every ``STEP_PERIOD`` takes the queued
  ``torque_request``, ``rig_state`` and ``clutch_estimate`` messages (polled, raw) and
  publishes a ``pressure_command``, as the controller with its timer trigger.

Every message is serialised once at the start and published as bytes (the nodes publish the
bytes of their CDR codecs). The nodes are rclpy nodes with parameter services and rosout, as
the chain's. ``python -m benchmarks.live_cpu --skeleton`` runs the three beside the demo
under the namespace ``/skeleton`` (their own topics; the rig_state rate the demo's) and prints
their CPU beside the chain's: what the chain's messages cost in rclpy and DDS on this machine
before any of its work, the part of the budget no change inside the nodes can remove.
"""

from __future__ import annotations

import argparse
import bisect
import json
import sys
import threading
import time
from pathlib import Path

__all__ = ["PUMP_PERIOD", "RIG_RATE", "ROLES", "STEP_PERIOD", "main", "published_between"]

ROLES = ("bridge", "estimator", "controller")
RIG_RATE = 108.0  # [Hz] rig_state in the demo (live_cpu counts it from the demo's bag)
PUMP_PERIOD = 0.01  # [s] the bridge's pump cycle (params: pump.period)
STEP_PERIOD = 0.01  # [s] the controller's step (params: controller.rate 100 Hz)
LAMELLAS = 8  # per-lamella arrays of clutch_estimate (the flexiforce_8 preset)
#: messages published per topic by this process (``--report``)
PUBLISHED: dict[str, int] = {}
READY = [float("nan")]  # [s] epoch at which the node was built (``--report``)
SAMPLE_PERIOD = 0.5  # [s] between two samples of the counts (``--report``)


def _messages() -> dict[str, bytes]:
    """Return the serialised message of each topic, with realistic field sizes."""
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState
    from rclpy.serialization import serialize_message

    rig = RigState()
    rig.actuating_pressure, rig.lamella_temperature, rig.slip_speed = 20e5, 40.0, 1.047
    rig.measured_torque, rig.has_measured_torque = 600.0, True
    est = ClutchEstimate()
    est.lamella_normal_force = [1.0e4] * LAMELLAS
    est.spline_friction_force = [1.0e2] * LAMELLAS
    est.spline_law = "ff_v"
    cmd = PressureCommand()
    cmd.pressure, cmd.requested_torque, cmd.predicted_torque = 20e5, 600.0, 598.0
    cmd.reason = "tracking"
    return {"rig_state": serialize_message(rig), "clutch_estimate": serialize_message(est),
            "pressure_command": serialize_message(cmd),
            "pump_request": serialize_message(cmd)}  # (the same type: the applied command)


def _node_factory(role: str, rig_rate: float, published: dict[str, int]):
    """Return the factory of ``role``'s node (rclpy imported here: ``--help`` stays light)."""
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest
    from rclpy.node import Node

    from clutch_ros.interfaces import (
        CLUTCH_ESTIMATE,
        PRESSURE_COMMAND,
        PUMP_REQUEST,
        RIG_STATE,
        TORQUE_REQUEST,
    )
    from clutch_ros.nodes.cycle import Cycle
    from clutch_ros.nodes.polled import PolledSubscription
    from clutch_ros.nodes.qos import publisher_qos, sensor_qos, subscriber_qos

    data = _messages()

    def publisher(node, msg_type, topic):
        """Return a call that publishes ``topic``'s bytes and counts it in ``published``."""
        pub = node.create_publisher(msg_type, topic.name, publisher_qos(topic.name))
        raw, publish = data[topic.name], pub.publish
        published[topic.name] = 0

        def send(*_args) -> None:
            publish(raw)
            published[topic.name] += 1

        return send

    def on_error(job: str, err: BaseException) -> None:
        raise SystemExit(f"skeleton {role} {job}: {err}")

    class Bridge(Node):
        def __init__(self):
            super().__init__("skeleton_bridge")
            rig = publisher(self, RigState, RIG_STATE)
            report = publisher(self, PressureCommand, PUMP_REQUEST)
            commands = PolledSubscription(self, PressureCommand, PRESSURE_COMMAND.name,
                                          sensor_qos(), raw=True)

            def pump() -> None:
                commands.take()
                report()

            self.cycles = [Cycle("skeleton_rx", {"rig": (1.0 / rig_rate, rig)},
                                 on_error).start(),
                           Cycle("skeleton_pump", {"pump": (PUMP_PERIOD, pump)},
                                 on_error).start()]

    class Estimator(Node):
        def __init__(self):
            super().__init__("skeleton_estimator")
            estimate = publisher(self, ClutchEstimate, CLUTCH_ESTIMATE)
            self.create_subscription(RigState, RIG_STATE.name, estimate,
                                     subscriber_qos(RIG_STATE.name), raw=True)

    class Controller(Node):
        def __init__(self):
            super().__init__("skeleton_controller")
            command = publisher(self, PressureCommand, PRESSURE_COMMAND)
            inputs = [PolledSubscription(self, TorqueRequest, TORQUE_REQUEST.name,
                                         subscriber_qos(TORQUE_REQUEST.name, depth=5), raw=True),
                      PolledSubscription(self, RigState, RIG_STATE.name, sensor_qos(), raw=True),
                      PolledSubscription(self, ClutchEstimate, CLUTCH_ESTIMATE.name,
                                         sensor_qos(), raw=True)]

            def step() -> None:
                for sub in inputs:
                    sub.take()
                command()

            self.cycle = Cycle("skeleton_step", {"step": (STEP_PERIOD, step)},
                               on_error).start()

    node_class = {"bridge": Bridge, "estimator": Estimator, "controller": Controller}[role]

    def factory():
        node = node_class()
        READY[0] = time.time()
        return node

    return factory


def main(argv=None) -> int:
    """Run one skeleton node until SIGINT/SIGTERM."""
    argv = sys.argv[1:] if argv is None else list(argv)
    ros = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", choices=ROLES, help="which node of the chain")
    parser.add_argument("--rig-rate", type=float, default=RIG_RATE,
                        help=f"rig_state publications per second [Hz] (bridge; default "
                             f"{RIG_RATE:g})")
    parser.add_argument("--report", help="write the messages published per topic (JSON), "
                                         f"sampled every {SAMPLE_PERIOD:g} s, to this file "
                                         "at the end")
    args = parser.parse_args(argv[:ros])
    if not args.rig_rate > 0.0:
        parser.error(f"--rig-rate must be > 0 Hz, got {args.rig_rate}")
    from clutch_ros.nodes.runner import run_node

    factory = _node_factory(args.role, args.rig_rate, PUBLISHED)
    samples: list[tuple[float, dict[str, int]]] = []
    stop = threading.Event()

    def sample() -> None:  # the counts over time: a reader takes those of its own window
        while not stop.wait(SAMPLE_PERIOD):
            samples.append((time.time(), dict(PUBLISHED)))

    threading.Thread(target=sample, name="skeleton_counts", daemon=True).start()
    code = run_node(f"skeleton_{args.role}", f"bare {args.role} of the chain", [], factory,
                    argv[ros:])
    stop.set()
    if args.report:
        samples.append((time.time(), dict(PUBLISHED)))
        Path(args.report).write_text(json.dumps({"ready": READY[0], "samples": samples}))
    return code


def published_between(report: dict, start: float, end: float) -> dict[str, float]:
    """Return the messages per topic a ``--report`` counts from ``start`` to ``end`` [s epoch].

    Linear between its samples (every ``SAMPLE_PERIOD``); raises ValueError when the
    samples do not cover the interval.
    """
    times = [t for t, _ in report["samples"]]
    if not times or start < times[0] or end > times[-1]:
        raise ValueError(f"the counts cover {times[0] if times else 'nothing'}"
                         f"..{times[-1] if times else ''}, not {start}..{end}")

    def at(when: float) -> dict[str, float]:
        i = bisect.bisect_left(times, when)
        (t1, c1) = report["samples"][i]
        (t0, c0) = report["samples"][max(i - 1, 0)]
        f = 0.0 if t1 == t0 else (when - t0) / (t1 - t0)
        return {k: c0.get(k, 0) + f * (n - c0.get(k, 0)) for k, n in c1.items()}

    first, last = at(start), at(end)
    return {k: last[k] - first.get(k, 0.0) for k in last}


if __name__ == "__main__":
    raise SystemExit(main())
