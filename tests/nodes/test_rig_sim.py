"""The rig_sim node as a real process: what it puts on the bus, its parameters, its errors.

A python-can receiver in this process records the rig's private udp_multicast group.

* Operator mode: ``rig.slip_speed`` set at run time (as ``ros2 param set`` does) changes the
  shaft speed on the bus; out-of-range values and other parameters are refused.
* ``rig.scenario:=table3:1:10`` (Table 3, step 0 -> 40 bar -> 0, 10 rpm, DBP) puts exactly
  the pressure sequence of the offline run of the same plant and seed on the bus.
* Bad parameters stop the node at start with one clear line (exit code 2, no traceback).
"""

import math
import os
import signal
import time

import numpy as np
import pytest

from clutch_ros.canbus import RigDatabase
from clutch_ros.cli.processes import NodeProcess, isolated_ros_env, ros_param_args
from tests.canbus.recorder import BusRecorder, bus_params, private_group
from tests.nodes.rclpy_harness import Harness, assert_bad_settings_fail_at_start

pytestmark = pytest.mark.ros

DB = RigDatabase()
RIG_FAST, RIG_SPEED = DB.frame("RigFast").frame_id, DB.frame("RigSpeed").frame_id
BAR = 1e5


def _rig(params, logs):
    return NodeProcess("rig_sim", ["--ros-args", *ros_param_args(params)],
                       isolated_ros_env(int(os.environ["ROS_DOMAIN_ID"])), logs)


def _speeds(rec, since: int = 0) -> list[float]:
    return [DB.decode(f.arbitration_id, f.data)["InputShaftSpeed"]
            for f in rec.of(RIG_SPEED)[since:]]


def _set(h, client, name, value):
    from rclpy.parameter import Parameter

    return h.until_answered(lambda: client.set_parameters([Parameter(name, value=value)]),
                            f"set {name}").results[0]


def test_slip_speed_parameter_changes_the_bus(tmp_path):
    from rclpy.parameter_client import AsyncParameterClient

    group, port = private_group()
    with BusRecorder(group, port) as rec:
        rig = _rig({**bus_params(group, port), "rig.slip_speed": 0.0}, tmp_path)
        try:
            with Harness("rig_sim_param_test") as h:
                client = AsyncParameterClient(h.node, "rig_sim")
                h.spin_until(lambda: client.services_are_ready() and rec.count(RIG_SPEED)
                             > 200, 60.0, "the rig and its parameter services")
                assert all(abs(w) < 0.05 for w in _speeds(rec)[-100:])
                before = rec.count(RIG_SPEED)
                assert _set(h, client, "rig.slip_speed", 3.0).successful
                applied = rec.count(RIG_SPEED)  # counted from the reply: a slow reply is no bias
                rec.wait_for(lambda: rec.count(RIG_SPEED) > applied + 500, 30.0, "500 frames")
                after = _speeds(rec, before)
                assert np.mean(after[-100:]) == pytest.approx(3.0, abs=0.02)
                # the motor follows with its time constant: the change shows on the bus
                assert after[0] < 1.0 < 2.9 < max(after)
                refused = _set(h, client, "rig.slip_speed", 500.0)  # beyond +-100 rad/s
                assert not refused.successful
                refused = _set(h, client, "rig.dt", 0.002)  # read-only: the run's time base
                assert not refused.successful and "read-only" in refused.reason
                assert rig.alive()
        finally:
            rig.stop()


@pytest.mark.slow
def test_table3_scenario_pressure_sequence_on_the_bus(tmp_path):
    from rclpy.parameter_client import AsyncParameterClient

    from clutch_ros.rig import RigPlant
    from clutch_ros.rig.scenario import scenario_from_spec
    from clutch_ros.rig.simulator import run_offline

    scenario = scenario_from_spec("table3:1:10")  # 1 s lead-in, 10 s at 40 bar, 3 s lead-out
    truth = run_offline(RigPlant.from_file("rig_truth", seed=0), scenario)
    steps = len(truth["actuating_pressure"])
    group, port = private_group()
    with BusRecorder(group, port) as rec:
        rig = _rig({**bus_params(group, port), "rig.scenario": "table3:1:10"}, tmp_path)
        try:
            with Harness("rig_sim_scenario_test") as h:
                client = AsyncParameterClient(h.node, "rig_sim")
                h.spin_until(client.services_are_ready, 60.0, "the rig's parameter services")
                refused = _set(h, client, "rig.slip_speed", 2.0)
                assert not refused.successful and "operator mode" in refused.reason
            rec.wait_for(lambda: rec.count(RIG_FAST) >= steps, 150.0, f"{steps} RigFast")
        finally:
            rig.stop()
    frames = rec.of(RIG_FAST)[:steps]  # frame j: the signals after step j + 1 (t = j + 1 ms)
    counters = [DB.decode(RIG_FAST, f.data)["RigFast_Counter"] for f in frames]
    assert all(b == (a + 1) % 16 for a, b in zip(counters, counters[1:]))  # none lost
    bus = np.array([DB.decode(RIG_FAST, f.data)["ActuatingPressure"] for f in frames])
    t = np.arange(1, steps + 1) * 1e-3

    def span(a, b):
        return bus[(t > a) & (t <= b)] / BAR

    assert span(0.0, 0.99).max() < 0.5  # lead-in: 0 bar requested
    assert span(1.0, 1.5).max() > 41.0  # the step with the pump's pressure kick
    assert np.abs(span(3.0, 11.0) - 40.0).max() < 0.5  # held at 40 bar
    assert span(12.0, 14.0).max() < 0.5  # released
    # the same plant and seed offline: the bus carries exactly that run
    expected = np.clip(truth["actuating_pressure"], 0.0, None)
    assert np.abs(bus - expected).max() <= DB.signal("ActuatingPressure").resolution * 0.51
    speeds = [DB.decode(RIG_SPEED, f.data)["InputShaftSpeed"] for f in rec.of(RIG_SPEED)]
    assert np.mean(speeds[2000:10000]) == pytest.approx(10 * math.pi / 30, abs=0.01)  # 10 rpm


def _rig_reports(diags) -> list[tuple[int, float, int]]:
    """(level, lost_time_s, overruns) of each /rig_sim status received."""
    out = []
    for array in diags:
        for st in array.status:
            if st.name == "/rig_sim":
                kv = {v.key: v.value for v in st.values}
                out.append((st.level[0] if isinstance(st.level, bytes) else int(st.level),
                            float(kv["lost_time_s"]), int(kv["overruns"])))
    return out


def test_a_stalled_rig_reports_the_real_time_it_dropped(tmp_path):
    """SIGSTOP 0.5 s: the loop drops the backlog beyond 0.1 s and says so on /diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    group, port = private_group()
    with BusRecorder(group, port) as rec:
        rig = _rig(bus_params(group, port), tmp_path)
        try:
            with Harness("rig_sim_stall_test") as h:
                diags = h.collect(DiagnosticArray, "/diagnostics", 50)
                h.spin_until(lambda: _rig_reports(diags) and rec.count(RIG_FAST) > 500, 60.0,
                             "the rig's frames and a report")
                before = _rig_reports(diags)[-1][1]
                os.kill(rig.pid, signal.SIGSTOP)
                time.sleep(0.5)
                os.kill(rig.pid, signal.SIGCONT)
                n = len(_rig_reports(diags))
                h.spin_until(lambda: len(_rig_reports(diags)) > n + 1, 30.0, "two more reports")
                assert rig.alive()
        finally:
            rig.stop()
    reports = _rig_reports(diags)
    # 0.5 s stopped, at most max_lag (0.1 s) of it caught up; scheduling adds to it (atol)
    dropped = reports[-1][1] - before
    assert 0.35 <= dropped <= 1.0, reports
    assert reports[-1][2] >= 1
    warned = [r for r in reports[n - 1:] if r[0] == DiagnosticStatus.WARN[0]]
    assert warned, reports  # the report covering the stall is WARN


def test_bad_parameters_fail_at_start_with_one_line(ros_env):
    cases = {
        "table9:1:10": (["-p", "rig.scenario:=table9:1:10"], "bad rig scenario"),
        "rpm 0": (["-p", "rig.scenario:=table3:1:0"], "rpm"),
        "params file": (["-p", "rig.params_file:=/nonexistent/truth.yaml"], "nonexistent"),
        "dt range": (["-p", "rig.dt:=5.0"], "rig.dt"),
        "dt type": (["-p", "rig.dt:=fast"], "rig.dt"),
        "interface": (["-p", "can.interface:=nonsense"], "unknown CAN interface"),
    }
    assert_bad_settings_fail_at_start("rig_sim", cases, ros_env)
