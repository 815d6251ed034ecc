"""Live parameters through the real parameter service, and peer diagnostics, on node processes.

estimator and controller run as separate processes; this test node publishes rig_state (and
the torque requests) and talks to their rcl_interfaces SetParameters services:

- controller: ``controller.max_pressure`` lowered to 10 bar while commanding 40 bar: every
  command the controller publishes after the service answered is at most 10 bar; an
  inconsistent set (min above max) and an out-of-range value are refused with a reason and
  change nothing; the estimator's ``estimator.queue_depth`` is read-only and refused.
- estimator: ``estimator.max_sample_age`` lowered below the age of the samples sent: from then
  on they are skipped (no estimate), raised again: estimated again.
- peers: rig_state stops -> the controller's fail-safe reason and the estimator's diagnostic
  name the topic and this node, the silent publisher; hardware_id is the launch value.
"""

import time

import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, rig_state

pytestmark = pytest.mark.ros

PRESET = str(REPO / "params" / "flexiforce_8.yaml")
PROBE = "live_params_probe"


def _set(h, client, **values):
    from rclpy.parameter import Parameter

    params = [Parameter(k.replace("__", "."), value=v) for k, v in values.items()]
    return h.until_answered(lambda: client.set_parameters(params), f"set {values}").results


def _get(h, client, name):
    return h.until_answered(lambda: client.get_parameters([name]), f"get {name}").values[0]


def _status(arrays, name):
    for array in reversed(arrays):
        for status in array.status:
            if status.name == name:
                return status
    return None


def test_parameters_apply_live_and_peers_are_named(ros_env, tmp_path):
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, TorqueRequest
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter_client import AsyncParameterClient

    from clutch_ros.cli.processes import NodeProcess
    from clutch_ros.nodes.qos import reliable_qos, sensor_qos
    from clutch_ros.nodes.stamps import stamp_to_sec

    hw = ["-p", "diagnostics.hardware_id:=simulated rig"]
    procs = [NodeProcess("estimator", ["--ros-args", "--params-file", PRESET, *hw], ros_env,
                         tmp_path),
             NodeProcess("controller", ["--ros-args", "--params-file", PRESET, *hw], ros_env,
                         tmp_path)]
    state = {"age": 0.0, "rig": True}
    try:
        with Harness(PROBE) as h:
            commands = h.collect(PressureCommand, "pressure_command", reliable_qos())
            estimates = h.collect(ClutchEstimate, "clutch_estimate", sensor_qos())
            diags = h.collect(DiagnosticArray, "/diagnostics", reliable_qos(50))
            rig = h.node.create_publisher(type(rig_state(0.0)), "rig_state", reliable_qos(10))
            req = h.node.create_publisher(TorqueRequest, "torque_request", reliable_qos(10))

            def tick():
                now = time.time()
                if state["rig"]:
                    rig.publish(rig_state(now - state["age"], 30e5))
                msg = TorqueRequest()
                msg.torque = 5000.0  # far above what 40 bar gives: the limit binds
                req.publish(msg)

            h.node.create_timer(0.01, tick)
            ctl = AsyncParameterClient(h.node, "controller")
            est = AsyncParameterClient(h.node, "estimator")
            h.spin_until(lambda: ctl.services_are_ready() and est.services_are_ready(), 30.0,
                         "the parameter services")
            h.spin_until(lambda: commands and commands[-1].pressure >= 39e5, 30.0,
                         "the controller at its 40 bar limit")

            # controller: a lower max_pressure applies at once
            (ok,) = _set(h, ctl, controller__max_pressure=10e5)
            assert ok.successful, ok.reason
            answered = time.time()
            n = len(commands)
            h.spin_until(lambda: len(commands) >= n + 50, 10.0, "commands after the change")
            after = [c for c in commands if stamp_to_sec(c.header.stamp) >= answered]
            assert len(after) >= 40
            assert max(c.pressure for c in after) <= 10e5
            assert after[-1].pressure == pytest.approx(10e5) and "pressure limit" in \
                after[-1].reason

            (bad,) = _set(h, ctl, controller__min_pressure=20e5)
            assert not bad.successful and "must not exceed controller.max_pressure" in bad.reason
            (bad,) = _set(h, ctl, controller__max_pressure=-1.0)
            assert not bad.successful and bad.reason
            assert _get(h, ctl, "controller.min_pressure").double_value == 0.0
            assert _get(h, ctl, "controller.max_pressure").double_value == 10e5
            (ro,) = _set(h, est, estimator__queue_depth=5)
            assert not ro.successful and "read-only" in ro.reason, ro.reason

            # estimator: samples 0.3 s old are estimated at max_sample_age 0.5 s, skipped at 0.1
            state["age"] = 0.3
            h.spin_for(0.5)
            n = len(estimates)
            h.spin_until(lambda: len(estimates) >= n + 10, 10.0, "estimates of 0.3 s samples")
            (ok,) = _set(h, est, estimator__max_sample_age=0.1)
            assert ok.successful, ok.reason
            h.spin_for(0.3)
            n = len(estimates)
            h.spin_for(1.0)
            assert len(estimates) == n, "samples older than max_sample_age were estimated"
            (ok,) = _set(h, est, estimator__max_sample_age=0.5)
            h.spin_until(lambda: len(estimates) >= n + 10, 10.0, "estimates again")

            # peers: rig_state stops; both name the topic and its (silent) publisher
            state["rig"] = False
            h.spin_until(lambda: commands[-1].pressure == 0.0, 5.0, "fail-safe 0 Pa")
            reason = commands[-1].reason
            assert reason.startswith("fail-safe: stale rig data: no rig_state from "
                                     f"/{PROBE} for "), reason
            h.spin_until(lambda: "no rig_state" in getattr(_status(diags, "/estimator"),
                                                           "message", ""), 5.0,
                         "the estimator's diagnostic")
            status = _status(diags, "/estimator")
            assert f"stale rig data: no rig_state from /{PROBE} for" in status.message
            assert status.hardware_id == "simulated rig"
            assert _status(diags, "/controller").hardware_id == "simulated rig"
    finally:
        for proc in procs:
            proc.stop()
