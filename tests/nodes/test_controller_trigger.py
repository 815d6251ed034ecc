"""The controller process with ``controller.trigger: estimate``: one step per estimate.

A test node plays torque request, rig state and estimator to a real ``controller`` process
over DDS, every 10 ms, each estimate stamped with a time of its own (not the node clock's).
Every command must name the estimate it answers (its stamp), one per estimate; an estimate
stamped less than half a period after the last one is skipped, not answered. The fail-safe
holds in this mode: when rig_state stops (estimates go on), the commands answering the
estimates are 0 Pa naming the silent rig data; when the estimates stop, the watchdog commands
0 Pa naming the stale estimate, and commands resume when they return.
"""

import math

import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, assert_bad_settings_fail_at_start, node_process

pytestmark = pytest.mark.ros

PRESET = REPO / "params" / "flexiforce_8.yaml"
W10 = 10 * 2 * math.pi / 60  # [rad/s]
T0_NS = 50_000 * 10**9  # [ns] the estimates' own time base (far from the node clock's)
TICK_NS = 10_000_000


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


@pytest.fixture
def controller(ros_env):
    with node_process("controller", ros_env, "--params-file", str(PRESET),
                      "-p", "controller.trigger:=estimate") as proc:
        yield proc


def test_one_command_per_estimate_stamped_with_it_and_the_fail_safe_holds(controller):
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, TorqueRequest

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos
    from tests.nodes.rclpy_harness import rig_state

    with Harness("trigger_test") as h:
        commands = h.collect(PressureCommand, "pressure_command", reliable_qos())
        req_pub = h.node.create_publisher(TorqueRequest, "torque_request", reliable_qos())
        rig_pub = h.node.create_publisher(type(rig_state(0.0)), "rig_state", sensor_qos())
        est_pub = h.node.create_publisher(ClutchEstimate, "clutch_estimate", reliable_qos())
        sent: list[int] = []  # the estimates' stamps
        play = {"rig": True, "estimate": True, "extra": False}

        def tick():
            now = h.node.get_clock().now().nanoseconds * 1e-9
            req = TorqueRequest()
            req.torque = 600.0
            req_pub.publish(req)
            if play["rig"]:
                rig_pub.publish(rig_state(now))
            if not play["estimate"]:
                return
            est = ClutchEstimate()
            est.header.stamp.sec, est.header.stamp.nanosec = divmod(
                T0_NS + TICK_NS * len(sent), 10**9)
            est.lamella_temperature, est.slip_speed_filtered = 40.0, W10
            est.friction_scale, est.spline_gain_scale = 1.0, 1.0
            est.measured_torque = est.modelled_torque = math.nan
            est_pub.publish(est)
            sent.append(_ns(est.header.stamp))
            if play["extra"]:  # 1 ms after it: faster than controller.rate, skipped
                est.header.stamp.nanosec += 1_000_000
                est_pub.publish(est)

        h.node.create_timer(0.01, tick)
        h.spin_until(lambda: len(commands) > 30 and commands[-1].pressure > 10e5, 60.0,
                     "commands for 600 N m")
        start = len(commands)
        h.spin_for(1.0)
        play["extra"] = True
        h.spin_for(0.5)
        play["extra"] = False
        answered = [_ns(c.header.stamp) for c in commands[start:]]
        assert answered and set(answered) <= set(sent)  # each names an estimate ...
        assert len(answered) == len(set(answered))  # ... once; the extra ones unanswered
        assert sorted(answered) == answered
        assert len(answered) >= 0.8 * len([s for s in sent if s >= answered[0]])

        play["rig"] = False  # rig_state stops, estimates go on: their commands are 0 Pa
        h.spin_until(lambda: commands[-1].pressure == 0.0, 10.0, "0 Pa on stale rig data")
        assert "stale rig data" in commands[-1].reason, commands[-1].reason
        assert _ns(commands[-1].header.stamp) in sent  # still the answer to an estimate
        play["rig"] = True
        h.spin_until(lambda: commands[-1].pressure > 10e5, 10.0, "commands to resume")

        play["estimate"] = False  # the estimates stop: the watchdog commands 0 Pa
        h.spin_until(lambda: commands[-1].pressure == 0.0, 10.0, "0 Pa on a stale estimate")
        assert "stale estimate" in commands[-1].reason, commands[-1].reason
        h.spin_for(0.5)
        assert all(c.pressure == 0.0 for c in commands[-3:])  # repeated while stale
        play["estimate"] = True
        h.spin_until(lambda: commands[-1].pressure > 10e5, 10.0, "commands to resume")
        assert _ns(commands[-1].header.stamp) in sent
        assert controller.poll() is None, "controller died"


def test_an_unknown_trigger_fails_at_start(ros_env):
    assert_bad_settings_fail_at_start("controller", {
        "trigger": (["-p", "controller.trigger:=clock"], "controller.trigger must be one of"),
    }, ros_env)
