"""The test harness's service calls: resent until answered, and a slow answer still counts.

A real rclpy service in a second context (its own executor thread) answers every request
0.3 s late; the harness resends every 0.1 s. The first answer, to the first request, must be
returned (a harness that only awaited its newest request would time out), and the requests
that were resent meanwhile were really sent.
"""

import threading
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from tests.nodes.rclpy_harness import Harness

pytestmark = pytest.mark.ros


def test_a_slow_answer_to_an_earlier_request_is_returned():
    from lifecycle_msgs.srv import GetState

    served = []

    def slow(request, response):
        time.sleep(0.3)
        served.append(time.monotonic())
        response.current_state.label = f"answer {len(served)}"
        return response

    context = rclpy.context.Context()
    rclpy.init(context=context)
    server = Node("slow_server", context=context)
    server.create_service(GetState, "slow_state", slow)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(server)
    stop = threading.Event()
    thread = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05)
                                              for _ in iter(stop.is_set, True)], daemon=True)
    thread.start()
    try:
        with Harness("slow_client") as h:
            client = h.node.create_client(GetState, "slow_state")
            assert client.wait_for_service(timeout_sec=10.0)
            sent = []

            def send():
                sent.append(time.monotonic())
                return client.call_async(GetState.Request())

            start = time.monotonic()
            answer = h.until_answered(send, "slow_state", timeout=10.0, resend=0.1,
                                      drop=client.remove_pending_request)
            took = time.monotonic() - start
    finally:
        stop.set()
        thread.join(2.0)
        executor.shutdown()
        server.destroy_node()
        rclpy.try_shutdown(context=context)
    assert answer.current_state.label == "answer 1"  # the first request's answer
    assert took < 5.0
    assert len(sent) >= 3  # resent every 0.1 s while the first (0.3 s) answer was on its way
