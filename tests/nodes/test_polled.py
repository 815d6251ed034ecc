"""PolledSubscription over real DDS: no executor takes its messages; take() gets them all.

A node with a polled subscription spins on the lean executor (the nodes' default) while a
peer publishes: the messages stay queued for :meth:`PolledSubscription.take`, in publishing
order, with reception times on the system clock; :meth:`take_newest` drops the older ones,
raw takes decode to the same message, and the subscription is in the ROS graph.
"""

from __future__ import annotations

import time

import pytest
import rclpy
from clutch_msgs.msg import RigState
from rclpy.node import Node

from clutch_ros.nodes.lean_executor import LeanExecutor
from clutch_ros.nodes.polled import PolledSubscription
from clutch_ros.nodes.qos import reliable_qos
from tests.nodes.rclpy_harness import Harness, rig_state
from tests.nodes.test_lean_executor import _spin_in_thread

pytestmark = pytest.mark.ros


def test_polled_messages_wait_for_take_in_order_with_reception_times():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = Node("polled_probe", context=context)
    polled = PolledSubscription(node, RigState, "polled_rig", reliable_qos(20))
    raw = PolledSubscription(node, RigState, "polled_rig", reliable_qos(20), raw=True)
    executor = LeanExecutor(context=context)
    executor.add_node(node)
    thread, errors = _spin_in_thread(executor)
    taken: list = []
    try:
        with Harness("polled_peer") as peer:
            pub = peer.node.create_publisher(RigState, "polled_rig", reliable_qos(20))
            # matched by the publisher, and in the ROS graph as subscriptions of the node
            peer.spin_until(lambda: pub.get_subscription_count() >= 2 and sum(
                i.node_name == "polled_probe" for i in
                peer.node.get_subscriptions_info_by_topic("/polled_rig")) == 2, 30.0,
                "both polled subscriptions")
            assert polled.topic_name == "/polled_rig"
            before = time.time()
            for i in range(10):
                pub.publish(rig_state(100.0 + i, pressure=1e5 * i))

            def got_all() -> bool:
                taken.extend(polled.take())
                return len(taken) >= 10

            peer.spin_until(got_all, 30.0, "10 messages taken")
            after = time.time()
            raw_items: list = []

            def got_raw() -> bool:
                raw_items.extend(raw.take())
                return len(raw_items) >= 10

            peer.spin_until(got_raw, 30.0, "10 raw messages taken")
            for i in range(10, 13):
                pub.publish(rig_state(100.0 + i, pressure=1e5 * i))
            newest: list = []

            def got_newest() -> bool:  # take_newest keeps the last of what is queued
                item = polled.take_newest()
                if item is not None:
                    newest.append(item)
                return polled.taken >= 13

            peer.spin_until(got_newest, 30.0, "the 3 newer messages")
    finally:
        rclpy.try_shutdown(context=context)
        thread.join(10.0)
    assert not errors, errors
    assert [m.message.actuating_pressure for m in taken] == [1e5 * i for i in range(10)]
    received = [m.received for m in taken]
    assert all(r is not None and before - 1.0 <= r <= after + 1.0 for r in received), received
    assert received == sorted(received)
    assert all(isinstance(item.message, bytes) for item in raw_items)
    assert [raw.decode(item.message).actuating_pressure for item in raw_items] == \
        [1e5 * i for i in range(10)]
    assert newest[-1].message.actuating_pressure == 12e5
    assert len(newest) <= 3 and polled.taken == 13
    polled.destroy()
    raw.destroy()
    executor.shutdown()
    node.destroy_node()
