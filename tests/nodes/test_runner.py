"""Slow set-up while a node is built gives way to a stop signal (``run_interruptibly``).

The process cases run a real node process (``run_node`` with a real rclpy node whose build
waits on a slow load, as the can_bridge's configure waits on numba) and stop it with a real
signal, as ``ros2 launch`` does.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading

import pytest

from clutch_ros.nodes.runner import run_interruptibly
from tests.conftest import REPO
from tests.nodes.rclpy_harness import wait_for_line

#: a node process whose build loads for argv[1] seconds; each step prints a line
PROBE = """
import sys, time
from rclpy.node import Node
from clutch_ros.errors import ClutchError
from clutch_ros.nodes.runner import run_interruptibly, run_node

def factory():
    node = Node("runner_probe")
    print("loading", flush=True)
    if not run_interruptibly(lambda: time.sleep(float(sys.argv[1])),
                             lambda: not node.context.ok()):
        print("stopped while loading", flush=True)
        raise ClutchError("stopped while loading")  # as the bridge's configure fails
    print("loaded", flush=True)
    return node

sys.exit(run_node("probe", "a probe", [], factory, []))
"""

SIGNALS = pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM],
                                  ids=["SIGINT", "SIGTERM"])


def _start(load_s: float, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", PROBE, str(load_s)], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.ros
@SIGNALS
def test_a_stop_during_a_slow_load_exits_0_without_waiting_for_it(signum, ros_env):
    proc = _start(600.0, ros_env)  # a load that would outlast the test's timeout
    try:
        wait_for_line(proc, "loading")
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=60)  # (600 s if the load were waited for)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    assert "stopped while loading" in out and "loaded" not in out


@pytest.mark.ros
@SIGNALS
def test_a_load_that_ends_lets_the_node_run_until_stopped(signum, ros_env):
    proc = _start(0.05, ros_env)
    try:
        wait_for_line(proc, "loaded")
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, out


def test_the_loads_result_and_its_failure_reach_the_caller():
    done = []
    assert run_interruptibly(lambda: done.append(threading.current_thread().name),
                             lambda: False, poll_s=0.01)
    assert done and done[0] != threading.current_thread().name  # it ran, in its own thread

    def fail():
        raise OSError("numba cache unreadable")

    with pytest.raises(OSError, match="numba cache unreadable"):
        run_interruptibly(fail, lambda: False, poll_s=0.01)


def test_a_stop_gives_up_the_wait_at_once():
    release = threading.Event()
    try:
        assert not run_interruptibly(release.wait, lambda: True, poll_s=0.01)
    finally:
        release.set()  # (the abandoned thread ends)
