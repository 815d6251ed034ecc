"""The node runner's preload: before rclpy.init, and a stop meanwhile ends the process at once.

Each case runs a real process (``run_node`` with a real rclpy node) and stops it with a real
signal, as ``ros2 launch`` does; the in-process case checks that a failing preload is raised
and leaves Python's signal handlers as they were.
"""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.ros

#: a node process whose preload sleeps argv[1] seconds; each step prints a line
PROBE = """
import sys, time
from rclpy.node import Node
from clutch_ros.nodes.runner import run_node

def preload():
    print("preloading", flush=True)
    time.sleep(float(sys.argv[1]))
    print("preloaded", flush=True)

def factory():
    print("built", flush=True)
    return Node("runner_probe")

sys.exit(run_node("probe", "a probe", [], factory, [], preload=preload))
"""


def _start(preload_s: float, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", PROBE, str(preload_s)], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_for(proc: subprocess.Popen, line: str) -> list[str]:
    seen = []
    assert proc.stdout is not None
    for got in proc.stdout:
        seen.append(got.strip())
        if got.strip() == line:
            return seen
    raise AssertionError(f"the process ended before {line!r}: {seen}")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_during_the_preload_exits_0_without_waiting_for_it(signum, ros_env):
    proc = _start(600.0, ros_env)  # a preload that would outlast the test's timeout
    try:
        _wait_for(proc, "preloading")
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=60)  # (600 s if the preload were waited for)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    assert "built" not in out  # no node, no ROS context: nothing was started


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_the_preload_ends_before_the_node_is_built(signum, ros_env):
    proc = _start(0.05, ros_env)
    try:
        seen = _wait_for(proc, "built")
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert seen[-3:] == ["preloading", "preloaded", "built"]
    assert proc.returncode == 0, out


def test_a_failing_preload_is_raised_and_the_signal_handlers_are_put_back():
    from clutch_ros.nodes.runner import run_nodes

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    built = []

    def preload():
        raise OSError("numba cache unreadable")

    with pytest.raises(OSError, match="numba cache unreadable"):
        run_nodes("probe", [lambda: built.append(1)], [], preload=preload)
    assert built == []
    assert {s: signal.getsignal(s) for s in before} == before
