"""The estimator node as a real process: estimates per sample, bad samples skipped and diagnosed.

A test node publishes RigState over DDS to an ``estimator`` process: valid samples interleaved
with a NaN sample, a duplicated stamp and an out-of-order stamp. Every valid sample gets one
ClutchEstimate with the same stamp, no estimate carries a NaN torque, none of the bad stamps
comes back, the skips are reported on /diagnostics, and the node is still running.
"""

import math

import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, node_process, rig_state

pytestmark = pytest.mark.ros

PRESET = REPO / "params" / "flexiforce_8.yaml"


@pytest.fixture
def estimator(ros_env):
    with node_process("estimator", ros_env, "--params-file", str(PRESET),
                      "-p", "estimator.max_sample_age:=0.0") as proc:
        yield proc


def test_estimates_per_sample_and_bad_samples_skipped(estimator):
    from clutch_msgs.msg import ClutchEstimate, RigState
    from diagnostic_msgs.msg import DiagnosticArray

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos
    from clutch_ros.nodes.stamps import stamp_to_sec

    with Harness() as h:
        estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
        diags = h.collect(DiagnosticArray, "/diagnostics", 10)
        pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
        h.spin_until(lambda: pub.get_subscription_count() > 0
                     and h.node.count_publishers("clutch_estimate") > 0, 30.0,
                     "the estimator to connect")
        h.spin_for(0.5)
        t0 = 1_700_000_000.0
        valid, bad = [], []
        for i in range(60):
            t = t0 + 0.01 * i
            pub.publish(rig_state(t, pressure=5e5 + 5e4 * i))
            valid.append(t)
            if i == 20:
                nan_msg = rig_state(t + 0.005)
                nan_msg.actuating_pressure = math.nan
                pub.publish(nan_msg)
                bad.append(t + 0.005)
            if i == 30:
                pub.publish(rig_state(t))  # duplicate stamp
            if i == 40:
                pub.publish(rig_state(t - 0.015))  # out of order
                bad.append(t - 0.015)
            h.spin_for(0.004)
        h.spin_until(lambda: len(estimates) >= len(valid), 20.0, "all estimates")
        wanted = {"skipped_NonFiniteSample", "skipped_DuplicateSample",
                  "skipped_OutOfOrderSample"}
        h.spin_until(lambda: wanted <= {kv.key for d in diags for s in d.status
                                        for kv in s.values}, 10.0, "skip diagnostics")
        assert estimator.poll() is None, "estimator died"

    stamps = [round(stamp_to_sec(e.header.stamp), 6) for e in estimates]
    assert stamps == [round(t, 6) for t in valid]
    assert all(math.isfinite(e.modelled_torque) for e in estimates)
    assert not {round(t, 6) for t in bad} & set(stamps)
    last = estimates[-1]
    assert last.spline_law and len(last.lamella_normal_force) == 8
    assert last.modelled_torque > 0.0 and math.isfinite(last.torque_accuracy)
    keys = {kv.key: kv.value for d in diags for s in d.status if "estimator" in s.name
            for kv in s.values}
    skipped = {k: int(v) for k, v in keys.items() if k.startswith("skipped_")}
    assert skipped.get("skipped_NonFiniteSample", 0) >= 1, keys
    assert skipped.get("skipped_DuplicateSample", 0) >= 1, keys
    assert skipped.get("skipped_OutOfOrderSample", 0) >= 1, keys


def test_events_executor_choice_is_warned_about(ros_env, tmp_path):
    """``--executor events`` starts, but says at once that it is experimental and why."""
    import time

    from clutch_ros.cli.processes import NodeProcess
    from clutch_ros.nodes.runner import EVENTS_WARNING

    node = NodeProcess("estimator", ["--executor", "events", "--ros-args", "--params-file",
                                     str(PRESET)], ros_env, tmp_path)  # fmt: skip
    try:
        end = time.monotonic() + 30.0
        while "experimental" not in node.tail() and node.alive() and time.monotonic() < end:
            time.sleep(0.1)
        log = node.log_path.read_text()
    finally:
        node.kill()  # SIGKILL: this executor was seen to ignore SIGINT
        node.stop()  # closes the log
    assert "[WARN]" in log and EVENTS_WARNING in log.replace("\n", " "), log
