"""Real-time options (nodes/realtime.py): parsed, applied to every thread, refused with a WARN.

* ``rt.cpus`` values: integers (as ROS parses ``-p rt.cpus:=0`` and launch ``value="0"``),
  lists and ranges; anything else a clear error (property-based over random CPU sets).
* ``apply_realtime`` in a child process: SCHED_FIFO and the affinity reach every thread that
  exists at that moment and the threads started later (inheritance); an unprivileged process
  (setuid nobody) is refused SCHED_FIFO with the reason, and runs on.
* A real estimator process with ``rt.policy:=fifo`` and ``rt.cpus:=0`` (an integer): every
  thread of the process (DDS, executor) runs SCHED_FIFO on CPU 0, ``/estimator/realtime`` is
  OK on /diagnostics; with a CPU that does not exist it is WARN with the reason, the node runs
  on and still estimates.
"""

import os
import subprocess
import sys
import textwrap

import pytest
from hypothesis import given
from hypothesis import strategies as st

from clutch_ros.nodes.realtime import parse_cpus
from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, node_process, rig_state

ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def test_parse_cpus_forms():
    assert parse_cpus("") == frozenset()
    assert parse_cpus(0) == frozenset({0})
    assert parse_cpus("3") == frozenset({3})
    assert parse_cpus(" 0, 2-4 ,7") == frozenset({0, 2, 3, 4, 7})
    for bad, words in ((True, "expected CPU numbers"), ("a", "'a' is no CPU"),
                       ("3-1", "'3-1' is no CPU"), ("-1", "'-1' is no CPU"),
                       (1.5, "expected CPU numbers")):
        with pytest.raises(ValueError, match=words):
            parse_cpus(bad)


@given(st.sets(st.integers(0, 255), min_size=1, max_size=20))
def test_parse_cpus_round_trips_any_set(cpus):
    text = ",".join(str(c) for c in sorted(cpus))
    assert parse_cpus(text) == cpus


_CHILD = textwrap.dedent("""
    import os, sys, threading, time
    from clutch_ros.nodes.realtime import RealtimeSettings, apply_realtime
    if sys.argv[1] == "nobody":
        os.setgid(65534); os.setuid(65534)
    ready = threading.Event()
    early = threading.Thread(target=ready.wait)  # exists before the call
    early.start()
    report = apply_realtime(RealtimeSettings("fifo", 7, frozenset({0})))
    late = threading.Thread(target=time.sleep, args=(0.5,))  # started after it
    late.start()
    tids = [int(t) for t in os.listdir("/proc/self/task")]
    print(report.level, "|", report.message())
    print(sorted({os.sched_getscheduler(t) == os.SCHED_FIFO for t in tids}), len(tids))
    print(sorted({tuple(sorted(os.sched_getaffinity(t))) for t in tids}))
    ready.set()
""")


def _child(user: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _CHILD, user], cwd=REPO, text=True,
                          capture_output=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()


@pytest.mark.skipif(not ROOT, reason="needs the right to set SCHED_FIFO (root)")
def test_apply_reaches_every_thread_and_new_ones():
    level, fifo, cpus = _child("root")
    assert level.startswith("OK |") and "SCHED_FIFO priority 7" in level and "cpus 0" in level
    assert fifo == "[True] 3"  # main, the early and the late thread: all SCHED_FIFO
    assert cpus == "[(0,)]"


@pytest.mark.skipif(not ROOT, reason="drops to user nobody, which only root can")
def test_refused_for_an_unprivileged_process_with_the_reason():
    level, fifo, cpus = _child("nobody")
    assert level.startswith("WARN |"), level
    assert "SCHED_FIFO priority 7: Operation not permitted" in level and "CAP_SYS_NICE" in level
    assert level.endswith("applied: cpus 0")  # its own affinity a process may always set
    assert fifo.startswith("[False]")  # it runs on at the normal policy


def _status(diags, name):
    for array in reversed(diags):
        for status in array.status:
            if status.name == name:
                return status
    return None


def _collect_realtime(ros_env, *rt_args):
    from clutch_msgs.msg import ClutchEstimate, RigState
    from diagnostic_msgs.msg import DiagnosticArray

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    with node_process("estimator", ros_env, "-p", "estimator.max_sample_age:=0.0",
                      *rt_args) as proc, Harness("realtime_test") as h:
        diags = h.collect(DiagnosticArray, "/diagnostics", 50)
        estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
        pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
        h.spin_until(lambda: _status(diags, "/estimator/realtime") is not None, 60.0,
                     "the estimator's /realtime status")
        h.spin_until(lambda: pub.get_subscription_count() > 0, 30.0, "the estimator")
        h.spin_until(lambda: (pub.publish(rig_state(1000.0 + len(estimates) * 0.01))
                              or len(estimates) >= 3), 30.0, "estimates")
        tids = [int(t) for t in os.listdir(f"/proc/{proc.pid}/task")]
        policies = {os.sched_getscheduler(t) for t in tids}
        affinities = {tuple(sorted(os.sched_getaffinity(t))) for t in tids}
        assert proc.poll() is None
        return _status(diags, "/estimator/realtime"), policies, affinities, len(tids)


@pytest.mark.ros
@pytest.mark.skipif(not ROOT, reason="needs the right to set SCHED_FIFO (root)")
def test_node_runs_every_thread_fifo_on_the_chosen_cpu(ros_env):
    from diagnostic_msgs.msg import DiagnosticStatus

    status, policies, affinities, threads = _collect_realtime(
        ros_env, "-p", "rt.policy:=fifo", "-p", "rt.priority:=10", "-p", "rt.cpus:=0")
    assert status.level == DiagnosticStatus.OK, status.message
    assert "SCHED_FIFO priority 10" in status.message and "cpus 0" in status.message
    assert threads > 3  # executor and DDS threads, all of them:
    assert policies == {os.SCHED_FIFO} and affinities == {(0,)}


@pytest.mark.ros
def test_node_refused_option_is_a_warn_and_it_runs_on(ros_env):
    from diagnostic_msgs.msg import DiagnosticStatus

    status, policies, affinities, _ = _collect_realtime(ros_env, "-p", "rt.cpus:=4095")
    assert status.level == DiagnosticStatus.WARN
    assert "refused" in status.message and "cpus [4095]" in status.message, status.message
    assert policies == {os.SCHED_OTHER} and (4095,) not in affinities
