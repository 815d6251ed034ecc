"""The can_bridge's pump_request reports on simulated time, as a real process.

On simulated time (a lock-step rig's ``/clock``) the rig keys each tick's answer on the
bridge's report of the tick's command: its stamp and torques (:mod:`clutch_ros.nodes.lockstep`).
So a report of a frame that answers no command must never look like the report of a command
the bridge did not admit. The fault this guards against: the periodic report before the first
admitted command was stamped with the node clock and zero torques, matched the controller's
first commands (fail-safe 0 bar, zero torques) stamped at that tick while the bridge still
refused them (their publisher was not yet in its ROS graph), and the rig counted the tick as
answered; the next tick's wait then expired (30 s, ``test_demo``'s lock-step timeout).

Here this process plays the rig's clock (``/clock`` in 10 ms ticks) and two command sources:
``impostor`` (refused: ``pump.command_source`` is ``controller``) and ``controller``.
"""

import os

import pytest

from clutch_ros.cli.processes import NodeProcess, isolated_ros_env, ros_param_args
from clutch_ros.nodes.lockstep import EPOCH_NS
from tests.canbus.recorder import bus_params, private_group
from tests.nodes.rclpy_harness import Harness

pytestmark = pytest.mark.ros

TICK_NS = 10_000_000


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_sim_time_reports_are_keyed_by_admitted_commands_only(tmp_path):
    from clutch_msgs.msg import PressureCommand
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    group, port = private_group()
    bridge = NodeProcess("can_bridge", ["--ros-args", *ros_param_args(
        {**bus_params(group, port), "use_sim_time": True,
         "pump.command_source": "controller", "pump.watchdog_timeout": 1.0,
         "pump.rise_rate_limit": 100e5})],  # [Pa/s]: 1 bar per 10 ms frame
        isolated_ros_env(int(os.environ["ROS_DOMAIN_ID"])), tmp_path)
    try:
        with Harness("impostor") as h:
            controller = Node("controller", context=h.context)
            h.executor.add_node(controller)
            clock_pub = h.node.create_publisher(Clock, "/clock", 10)
            publishers = {"impostor": h.node.create_publisher(
                PressureCommand, "pressure_command", 10),
                "controller": controller.create_publisher(
                PressureCommand, "pressure_command", 10)}
            reports = h.collect(PressureCommand, "pump_request", 100)
            tick = [EPOCH_NS]
            sent: dict[str, list[int]] = {"impostor": [], "controller": []}

            def step(source: str | None, pressure: float = 0.0, torques=(0.0, 0.0)) -> None:
                """Advance /clock one tick; ``source`` sends a command stamped at it."""
                tick[0] += TICK_NS
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = divmod(tick[0], 10**9)
                clock_pub.publish(clock)
                if source is not None:
                    cmd = PressureCommand(pressure=pressure, requested_torque=torques[0],
                                          predicted_torque=torques[1])
                    cmd.header.stamp = clock.clock
                    publishers[source].publish(cmd)
                    sent[source].append(tick[0])
                h.spin_for(0.01)

            # refused commands (the impostor's), zero torques, stamped at each tick, until
            # the bridge has reported its first (periodic, 'no command yet') frame
            h.spin_until(lambda: (step("impostor") or reports), 60.0, "a pump_request report")
            for _ in range(30):
                step("impostor")
            refused = list(reports)
            assert refused and all(r.reason == "no command yet" for r in refused), \
                [(r.reason, _ns(r.header.stamp)) for r in refused]
            # no report may carry the stamp of a command the bridge refused
            assert all(_ns(r.header.stamp) == 0 for r in refused), \
                [_ns(r.header.stamp) - EPOCH_NS for r in refused]

            # the controller's commands: each reported with its stamp and torques at once;
            # the rate-limited ramp's periodic reports (1 bar per frame towards the newest
            # admitted command's 20 bar) carry that command's stamp and zero torques
            admitted = len(reports)
            h.spin_until(lambda: (step("controller", 20e5, (400.0, 390.0))
                                  or len(reports) > admitted), 30.0, "a command's report")
            for _ in range(10):  # /clock runs on without commands: the ramp goes on
                step(None)
            answers = reports[admitted:]
            commands = [r for r in answers if (r.requested_torque, r.predicted_torque)
                        == (400.0, 390.0)]
            periodic = [r for r in answers if (r.requested_torque, r.predicted_torque)
                        == (0.0, 0.0)]
            assert len(commands) + len(periodic) == len(answers)
            # (the first commands may be refused too: the bridge learns the controller's
            # publisher from its ROS graph, refreshed at most every 0.2 s)
            admitted_stamps = sorted(_ns(r.header.stamp) for r in commands)
            assert admitted_stamps and set(admitted_stamps) <= set(sent["controller"])
            assert len(periodic) >= 5, [r.pressure for r in answers]
            assert all(_ns(r.header.stamp) in admitted_stamps for r in periodic)
            # the last ones (no command since) carry the newest admitted command's stamp
            assert _ns(periodic[-1].header.stamp) == admitted_stamps[-1]
            assert [r.pressure for r in answers] == sorted(r.pressure for r in answers)
            assert all(_ns(r.header.stamp) not in sent["impostor"] for r in reports)
            assert bridge.alive()
    finally:
        bridge.stop()
