"""A small in-test rclpy harness: one node, helpers to wait for peers and collect messages."""

from __future__ import annotations

import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


class Harness:
    """Context manager owning an rclpy context, one node and an executor."""

    def __init__(self, name: str = "test_harness"):
        self.name = name
        self.received: dict[str, list] = {}

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
        self.node.create_subscription(msg_type, topic, bucket.append, qos)
        return bucket

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
