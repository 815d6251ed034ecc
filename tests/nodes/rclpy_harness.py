"""A small in-test rclpy harness: one node, helpers to wait for peers and collect messages."""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


def rig_state(t: float, pressure: float = 20e5):
    """Return a valid RigState stamped ``t`` [s]: ``pressure`` [Pa], 40 °C, 10 rpm, 500 N m."""
    from clutch_msgs.msg import RigState

    from clutch_ros.nodes.stamps import sec_to_stamp

    msg = RigState()
    sec_to_stamp(t, msg.header.stamp)
    msg.actuating_pressure = pressure
    msg.lamella_temperature = 40.0
    msg.slip_speed = 10 * 2 * math.pi / 60
    msg.measured_torque = 500.0
    msg.has_measured_torque = True
    return msg


class Harness:
    """Context manager owning an rclpy context, one node and an executor."""

    def __init__(self, name: str = "test_harness"):
        self.name = name
        self.received: dict[str, list] = {}
        self.subscriptions: dict[str, object] = {}

    def __enter__(self) -> Harness:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = Node(self.name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        return self

    def __exit__(self, *exc) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def collect(self, msg_type, topic: str, qos) -> list:
        """Subscribe and return the list that fills with received messages."""
        bucket = self.received.setdefault(topic, [])
        self.subscriptions[topic] = self.node.create_subscription(msg_type, topic,
                                                                  bucket.append, qos)
        return bucket

    def wait_matched(self, topics, timeout: float = 30.0) -> None:
        """Spin until each collecting subscription on ``topics`` has matched a publisher.

        This is the reader's own match count (``rmw_subscription_count_matched_publishers``).
        A publisher that counts this reader among its matches may still send before the reader
        has matched it in turn (DDS discovery is asymmetric): best-effort samples sent in that
        window are lost. Start a publisher that waits for its readers only after this.
        """
        subs = [self.subscriptions[t] for t in topics]
        self.spin_until(lambda: all(s.get_publisher_count() >= 1 for s in subs), timeout,
                        f"publishers matched on {list(topics)}")

    def spin_for(self, seconds: float) -> None:
        """Spin for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def spin_until(self, condition, timeout: float, what: str) -> None:
        """Spin until ``condition()`` is true; fail the test after ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.01)

    def call(self, client, request, timeout: float = 30.0, resend: float = 2.0):
        """Call a service and return its response; for *idempotent* requests only.

        ``wait_for_service`` returns once the client has matched the service, but the
        service's response writer may not have matched the client's response reader yet
        (DDS discovery is asymmetric; ros2/ros2#1253, ros2/rmw_connextdds#132): that first
        response is lost and a plain ``call_async`` waits for ever. So the request is sent
        again every ``resend`` seconds [s] until one answer arrives, within ``timeout`` [s]
        in all (``resend`` inf: sent once, for a request that is not idempotent).
        """
        end = time.monotonic() + timeout
        assert client.wait_for_service(timeout_sec=timeout), client.srv_name
        return self.until_answered(lambda: client.call_async(request), client.srv_name,
                                   max(end - time.monotonic(), 0.0), resend,
                                   client.remove_pending_request)

    def until_answered(self, send, what: str, timeout: float = 30.0, resend: float = 2.0,
                       drop=None):
        """Return the first answer to ``send()``'s requests, sending again every ``resend`` s.

        For idempotent requests (see :meth:`call`), e.g. ``lambda:
        parameter_client.set_parameters([...])``. Every request sent stays awaited: a slow
        answer to an earlier one counts as well as the answer to the latest. ``drop(future)``
        forgets the ones still unanswered at the end.
        """
        end = time.monotonic() + timeout
        pending = []
        try:
            while True:
                pending.append(send())
                again = min(end, time.monotonic() + resend)
                while time.monotonic() < again:
                    done = next((f for f in pending if f.done()), None)
                    if done is not None:
                        return done.result()
                    self.executor.spin_once(timeout_sec=0.01)
                if time.monotonic() >= end:
                    done = next((f for f in pending if f.done()), None)
                    if done is not None:
                        return done.result()
                    raise AssertionError(f"timed out after {timeout:.1f} s waiting for the "
                                         f"answer of {what} ({len(pending)} requests sent)")
        finally:
            for future in pending:
                if drop is not None and not future.done():
                    drop(future)


def wait_for_line(proc: subprocess.Popen, line: str) -> list[str]:
    """Read ``proc``'s stdout until a line equal to ``line``; return the lines read.

    AssertionError (with what it printed) when the process ends first.
    """
    seen = []
    assert proc.stdout is not None
    for got in proc.stdout:
        seen.append(got.strip())
        if got.strip() == line:
            return seen
    raise AssertionError(f"the process ended before {line!r}: {seen}")


def assert_bad_settings_fail_at_start(node: str, cases: dict, env: dict) -> None:
    """Start ``clutch_ros.nodes.<node>`` once per case ``{name: (ros args, text)}``.

    Each must exit 2 with exactly one ``<node>: error: ...`` line containing ``text`` and no
    traceback (the cases run in parallel).
    """
    import signal
    import subprocess
    import sys

    from tests.conftest import REPO

    # faulthandler: a process that hangs is stopped with SIGABRT and prints every thread's stack
    procs = {name: subprocess.Popen(
        [sys.executable, "-X", "faulthandler", "-m", f"clutch_ros.nodes.{node}", "--ros-args",
         *args], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for name, (args, _) in cases.items()}
    for name, proc in procs.items():
        try:
            out, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            out, err = proc.communicate(timeout=30)
            raise AssertionError(f"{node} {name}: no exit within 60 s; its stacks:\n{err}") \
                from None
        assert proc.returncode == 2, (name, proc.returncode, out, err)
        assert "Traceback" not in err, (name, err)
        lines = [line for line in err.splitlines() if line.startswith(f"{node}: error:")]
        assert len(lines) == 1 and cases[name][1] in lines[0], (name, err)


@contextmanager
def node_process(node: str, env: dict, *ros_args: str):
    """Run ``python -m clutch_ros.nodes.<node> --ros-args ROS_ARGS``; stop it when done.

    The node's output goes to a temporary file, not a pipe: a pipe nobody reads fills up
    (64 KiB) and then blocks a node that logs a lot. On exit: SIGTERM, then SIGKILL after 10 s.
    """
    from tests.conftest import REPO

    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen([sys.executable, "-m", f"clutch_ros.nodes.{node}", "--ros-args",
                                 *ros_args], cwd=REPO, env=env, stdout=log,
                                stderr=subprocess.STDOUT, text=True)
        try:
            yield proc
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)


def connect_estimator(h: Harness, *, timeout: float = 30.0):
    """Return (rig_state publisher, estimates list, parameter client) once all are matched."""
    from clutch_msgs.msg import ClutchEstimate, RigState
    from rclpy.parameter_client import AsyncParameterClient

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
    pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
    client = AsyncParameterClient(h.node, "estimator")
    h.spin_until(lambda: pub.get_subscription_count() > 0
                 and h.node.count_publishers("clutch_estimate") > 0
                 and client.services_are_ready(), timeout, "the estimator to connect")
    h.spin_for(0.5)
    return pub, estimates, client
