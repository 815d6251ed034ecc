"""LeanExecutor over real DDS: subscriptions, timers, parameter services, entity changes, stop."""

from __future__ import annotations

import threading
import time

import pytest
import rclpy
from clutch_msgs.msg import RigState
from rcl_interfaces.msg import Parameter, ParameterType, SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSPolicyKind, QoSProfile, ReliabilityPolicy

from clutch_ros.nodes.lean_executor import EVENT_POLL_PERIOD, SIGNAL_SHUTDOWN_WAIT, LeanExecutor
from clutch_ros.nodes.qos import sensor_qos
from tests.nodes.rclpy_harness import Harness, rig_state

pytestmark = pytest.mark.ros


class _Lean(Node):
    """A node using each entity kind the clutch_ros nodes use."""

    def __init__(self, context):
        super().__init__("lean_probe_node", context=context)
        self.received: list = []
        self.ticks = 0
        self.late_ticks = 0
        self.new_ticks = 0  # of the timer that replaces the first one at run time
        self.guarded = 0
        self.guard = self.create_guard_condition(self._on_guard)
        self.declare_parameter("gain", 1.0)
        self.add_on_set_parameters_callback(self._on_set)
        self.create_subscription(RigState, "rig_state", self._on_rig, sensor_qos())
        self._timer = self.create_timer(0.02, self._tick)
        self._late = None

    def _on_set(self, params):
        bad = [p for p in params if p.name == "gain" and p.value < 0.0]
        return SetParametersResult(successful=not bad, reason="gain must be >= 0" if bad else "")

    def _on_rig(self, msg) -> None:
        self.received.append(msg)
        # an entity created from a callback joins the wait set; made once the first timer has
        # ticked 5 times, so that count does not depend on how fast the samples come
        if self._late is None and len(self.received) >= 3 and self.ticks >= 5:
            self._late = self.create_timer(0.02, self._late_tick)

    def _tick(self) -> None:
        self.ticks += 1

    def _late_tick(self) -> None:
        self.late_ticks += 1
        if self.late_ticks == 3:  # a timer destroyed and another made, as a rate change does
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(0.02, self._new_tick)

    def _new_tick(self) -> None:
        self.new_ticks += 1

    def _on_guard(self) -> None:
        self.guarded += 1


def _set(peer: Harness, value: float):
    client = peer.node.create_client(SetParameters, "/lean_probe_node/set_parameters")
    req = SetParameters.Request()
    req.parameters = [Parameter(name="gain")]
    req.parameters[0].value.type = ParameterType.PARAMETER_DOUBLE
    req.parameters[0].value.double_value = value
    return peer.call(client, req).results[0]


def _spin_in_thread(executor) -> tuple[threading.Thread, list]:
    """Spin ``executor`` on a daemon thread; its exceptions (not a shutdown) go to the list."""
    errors: list = []

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as err:  # noqa: BLE001 - reported by the test
            errors.append(err)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    return thread, errors


def _start(node_class):
    """Start a ``node_class`` node in a context of its own, spun by a LeanExecutor thread."""
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = node_class(context)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    thread, errors = _spin_in_thread(executor)
    return context, node, executor, thread, errors


def test_lean_executor_runs_every_entity_kind_and_stops_on_context_shutdown():
    context, node, executor, thread, errors = _start(_Lean)
    try:
        with Harness("lean_peer") as peer:
            pub = peer.node.create_publisher(RigState, "rig_state", sensor_qos())
            peer.spin_until(lambda: pub.get_subscription_count() >= 1, 30.0, "the lean node")
            sent = 0

            def feed() -> bool:
                nonlocal sent
                pub.publish(rig_state(sent * 0.01))
                sent += 1
                return len(node.received) >= 20 and node.late_ticks >= 3 and node.new_ticks >= 3

            peer.spin_until(feed, 30.0, "20 messages and the late and new timers")
            ticks = node.ticks
            node.guard.trigger()  # from this thread, as another thread of a node would
            peer.spin_until(lambda: node.guarded == 1, 30.0, "the guard condition's callback")
            assert _set(peer, 2.5).successful
            refused = _set(peer, -1.0)
            assert not refused.successful and "gain must be >= 0" in refused.reason
    finally:
        rclpy.try_shutdown(context=context)
        thread.join(10.0)
    assert not thread.is_alive(), "spin did not end after the context shut down"
    assert not errors, errors
    assert node.get_parameter("gain").value == 2.5
    assert node.ticks >= 5 and node.ticks == ticks  # the destroyed timer ran no more
    assert executor.rebuilds >= 2  # the late timer made it rebuild the wait set
    assert all(m.actuating_pressure == node.received[0].actuating_pressure
               for m in node.received)
    executor.shutdown()
    node.destroy_node()


class _Cleanup(Node):
    """Destroys its publisher (and so the publisher's QoS event handler) from a service."""

    def __init__(self, context):
        super().__init__("lean_probe_node", context=context)
        self.pub = self.create_publisher(RigState, "rig_state_out", 10)
        self.declare_parameter("gain", 1.0)
        self.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, params):
        if self.pub is not None:  # as CanBridgeNode.on_cleanup does in change_state
            self.destroy_publisher(self.pub)
            self.pub = None
        return SetParametersResult(successful=True)


def test_an_entity_destroyed_by_a_service_callback_leaves_the_executor_serving():
    """Regression: the kept wait set still held the destroyed publisher's event handler.

    Its next fill raised InvalidHandle out of spin (the can_bridge process died after a
    lifecycle cleanup, so its get_state was never answered).
    """
    context, node, executor, thread, errors = _start(_Cleanup)
    try:
        with Harness("lean_peer") as peer:
            assert _set(peer, 2.0).successful  # destroys the publisher in the callback
            assert _set(peer, 3.0).successful  # still answered after that
    finally:
        rclpy.try_shutdown(context=context)
        thread.join(10.0)
    assert not errors, errors
    assert node.pub is None and node.get_parameter("gain").value == 3.0
    executor.shutdown()
    node.destroy_node()


class _Strict(Node):
    """A subscription that requires reliable delivery, with an incompatible-QoS callback."""

    def __init__(self, context):
        super().__init__("lean_probe_node", context=context)
        self.incompatible: list = []
        self.received: list = []
        self.ticks = 0
        events = SubscriptionEventCallbacks(incompatible_qos=self.incompatible.append)
        self.create_subscription(RigState, "rig_state_qos", self.received.append,
                                 QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE),
                                 event_callbacks=events)
        self.create_timer(0.01, self._tick)

    def _tick(self) -> None:
        self.ticks += 1


def test_qos_events_are_handled_although_they_join_the_wait_only_now_and_then():
    """The event handlers are polled every EVENT_POLL_PERIOD, busy or idle: the event comes.

    A best-effort publisher meets the reliable subscription: the middleware raises the
    requested-incompatible-QoS event, which must reach the callback while a 100 Hz timer keeps
    the executor waking (the handlers are then left out of most waits) and while it is idle.
    """
    context, node, executor, thread, errors = _start(_Strict)
    try:
        with Harness("lean_peer") as peer:
            pub = peer.node.create_publisher(  # incompatible: best effort offered
                RigState, "rig_state_qos",
                QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
            peer.spin_until(lambda: bool(node.incompatible), 30.0, "the incompatible-QoS event")
            assert node.ticks > 0 and not node.received
            assert node.incompatible[0].last_policy_kind == QoSPolicyKind.RELIABILITY
            peer.node.destroy_publisher(pub)
    finally:
        rclpy.try_shutdown(context=context)
        thread.join(10.0)
    assert not errors, errors
    executor.shutdown()
    node.destroy_node()


class _Quiet(Node):
    """A node with no timer (bag_player's kind): only a signal or a shutdown wakes its wait."""

    def __init__(self, context):
        super().__init__("lean_quiet_node", context=context)
        self.pub = self.create_publisher(RigState, "rig_state_quiet", 10)


def test_a_signal_stops_the_spin_although_the_shutdown_comes_after_the_wake_up():
    """The signal thread of rclpy triggers the SIGINT guard condition, then shuts down.

    Done here in that order, the shutdown 0.2 s later (a loaded machine): the spin must end,
    although the wait that the trigger woke saw the context still valid. The shutdown is the
    C-level one rclpy's signal thread makes (no Python on-shutdown callbacks, so nothing else
    wakes the executor).
    """
    context, node, executor, thread, errors = _start(_Quiet)
    try:
        time.sleep(2 * EVENT_POLL_PERIOD)  # waiting with no timeout (QoS events included)
        assert thread.is_alive()
        executor._sigint_gc.trigger()  # as rclpy's signal thread, first
        time.sleep(0.2)
        context.handle.shutdown()  # then rclpy::shutdown_contexts()
        thread.join(SIGNAL_SHUTDOWN_WAIT + 3.0)
        stopped = not thread.is_alive()
    finally:
        rclpy.try_shutdown(context=context)
        thread.join(10.0)
    assert stopped, "the spin did not end after the signal's guard condition and shutdown"
    assert not errors, errors
    executor.shutdown()
    node.destroy_node()
