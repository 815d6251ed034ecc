"""Every node stops with exit 0 on SIGINT and on SIGTERM, the way ``ros2 launch`` stops it.

``ros2 launch`` sends SIGINT, SIGTERM 5 s later and SIGKILL 5 s after that; a node must be
gone with exit 0 before the first escalation (a run still there then has failed: it is
stopped with SIGABRT instead, and its node, run with ``-X faulthandler``, prints every
thread's stack into the report). Each node here runs as a real process
(``python -m clutch_ros.nodes.<node>``) on a loaded machine (two busy processes beside it)
while this process publishes its inputs every few milliseconds, and a burst of them just
before the signal, so that the signal can land while the node takes a message: that was the
controller's exit 1 (``RuntimeError: Unable to convert call argument '0' to Python object``
from ``take_message``; the cause and the fix: :mod:`clutch_ros.nodes.runner`), about one stop
in seven under ``ros2 launch``, one to two in 60 here with the old runner. The controller,
which takes three topics, is stopped 15 times with SIGINT and 5 times with SIGTERM, every
other node 3 and 2 times, each at a random moment (seeded) once it is in the ROS graph. The
recorder stops by its own rules (tests/nodes/test_recorder.py).
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import IO

import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, rig_state

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PRESET = str(REPO / "params" / "flexiforce_8.yaml")
#: ros2 launch's wait after SIGINT before SIGTERM, and after SIGTERM before SIGKILL [s]
ESCALATION_S = 5.0
#: processes started at once (the machine has 2 cores, shared)
BATCH = 3
#: busy processes beside the nodes: a rig PC under load (rclpy's shutdown thread runs late)
HOGS = 2


def _ros_args(node: str, bag) -> list[str]:
    return {
        "controller": ["--params-file", PRESET],
        "estimator": ["--params-file", PRESET],
        "can_bridge": ["-p", "can.interface:=virtual", "-p", "can.channel:=shutdown_test"],
        "rig_sim": ["-p", "can.interface:=virtual", "-p", "can.channel:=shutdown_test"],
        "bag_player": ["-p", f"player.bag:={bag}", "-p", "player.loop:=true"],
        "dashboard": ["-p", "dashboard.port:=0"],
    }[node]


#: node -> (SIGINT stops, SIGTERM stops)
STOPS = {"controller": (15, 5), "estimator": (3, 2), "can_bridge": (3, 2), "rig_sim": (3, 2),
         "bag_player": (3, 2), "dashboard": (3, 2)}


@dataclass
class _Run:
    """One node process, stopped with ``signum`` as ros2 launch would."""

    node: str
    signum: int
    name: str
    proc: subprocess.Popen
    log: IO[str]
    delay: float  # [s] after the node is in the graph
    seen_at: float | None = None
    signalled_at: float | None = None
    sent: list[str] = field(default_factory=list)

    def step(self, now: float, in_graph: bool, burst) -> bool:
        """Advance launch's stop sequence; return True while the process has to be watched.

        ``burst()`` is called just before the first signal: the node is then busy taking.
        """
        if self.proc.poll() is not None:
            return False
        if self.seen_at is None:
            if in_graph:
                self.seen_at = now
            return True
        if self.signalled_at is None:
            if now - self.seen_at >= self.delay:
                burst()
                time.sleep(self.delay % 0.003)  # (0-3 ms: while the node takes the burst)
                self._send(self.signum, now)
            return True
        waited = now - self.signalled_at
        if len(self.sent) == 1 and waited > ESCALATION_S:
            # launch would escalate now; the run has failed already, so stop it with
            # SIGABRT instead: faulthandler (-X faulthandler) prints where every thread was
            self._send(signal.SIGABRT, now)
        elif waited > ESCALATION_S:
            self._send(signal.SIGKILL, now)
        return True

    def _send(self, signum: int, now: float) -> None:
        self.proc.send_signal(signum)
        self.sent.append(signal.Signals(signum).name)
        self.signalled_at = now

    def report(self) -> str:
        self.log.seek(0)
        return (f"{self.name}: exit {self.proc.returncode} after {self.sent}\n"
                f"{self.log.read()[-6000:]}")  # (with SIGABRT: every thread's stack)


class _Inputs:
    """Publishes every clutch topic a node takes, one message each per call, stamped now."""

    def __init__(self, h: Harness):
        from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest

        from clutch_ros.nodes.qos import reliable_qos
        from clutch_ros.nodes.stamps import sec_to_stamp

        def stamped(msg_type):
            def make(now: float):
                msg = msg_type()
                sec_to_stamp(now, msg.header.stamp)
                return msg
            return make

        # reliable: matches the best-effort (sensor data) and the reliable subscribers
        self.topics = [(h.node.create_publisher(msg_type, topic, reliable_qos(50)), make)
                       for topic, msg_type, make in [
                           ("rig_state", RigState, rig_state),
                           ("clutch_estimate", ClutchEstimate, stamped(ClutchEstimate)),
                           ("torque_request", TorqueRequest, stamped(TorqueRequest)),
                           ("pressure_command", PressureCommand, stamped(PressureCommand))]]

    def publish(self) -> None:
        now = time.time()
        for pub, make in self.topics:
            pub.publish(make(now))

    def burst(self, count: int = 20) -> None:
        """Publish ``count`` messages on every topic at once."""
        for _ in range(count):
            self.publish()


def _start(node: str, index: int, signum: int, env: dict, bag, rng) -> _Run:
    name = f"{node}_{index}"
    log = tempfile.TemporaryFile("w+")
    proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m",
                             f"clutch_ros.nodes.{node}", "--ros-args",
                             "-r", f"__node:={name}", *_ros_args(node, bag)],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
    return _Run(node, signum, name, proc, log, delay=rng.uniform(0.2, 1.5))


def _stop_all_as_launch_does(runs: list[_Run], h: Harness, inputs: _Inputs) -> None:
    """Publish inputs while each run goes through start -> signal -> exit (or escalation)."""
    end = time.monotonic() + 120.0 + 3 * ESCALATION_S
    watched = list(runs)
    while watched:
        assert time.monotonic() < end, [r.report() for r in watched]
        inputs.publish()
        h.executor.spin_once(timeout_sec=0.002)
        names = {n for n, _ in h.node.get_node_names_and_namespaces()}
        now = time.monotonic()
        watched = [r for r in watched if r.step(now, r.name in names, inputs.burst)]


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    from tests.bag.conftest import write_sample_bag

    path = tmp_path_factory.mktemp("shutdown") / "bag"
    write_sample_bag(path, "mcap", n=200)
    return path


@pytest.mark.parametrize("node", list(STOPS))
def test_node_exits_0_on_sigint_and_on_sigterm(node, ros_env, bag):
    rng = random.Random(f"shutdown-{node}")
    sigint, sigterm = STOPS[node]
    signals = [signal.SIGINT] * sigint + [signal.SIGTERM] * sigterm
    rng.shuffle(signals)
    runs: list[_Run] = []
    hogs: list[subprocess.Popen] = []
    with Harness(f"shutdown_{node}") as h:
        inputs = _Inputs(h)
        try:
            hogs += [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                     for _ in range(HOGS)]
            for first in range(0, len(signals), BATCH):
                batch = [_start(node, first + i, signum, ros_env, bag, rng)
                         for i, signum in enumerate(signals[first:first + BATCH])]
                runs += batch
                _stop_all_as_launch_does(batch, h, inputs)
        finally:
            for hog in hogs:
                hog.kill()
                hog.wait(10)
            for run in runs:
                if run.proc.poll() is None:
                    run.proc.kill()
                    run.proc.wait(10)
    failed = [r.report() for r in runs
              if r.proc.returncode != 0 or r.sent != [signal.Signals(r.signum).name]]
    for run in runs:
        run.log.close()
    assert not failed, "\n\n".join(failed)
    assert len(runs) == sigint + sigterm
