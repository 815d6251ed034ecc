"""A stand-alone rclpy process for tests: publish or receive one clutch_msgs type.

Usage:
    python pubsub_peer.py pub TYPE SECONDS   publish the reference message every 20 ms
    python pubsub_peer.py sub TYPE SECONDS   print the first received message as JSON, exit 0
Exit code 3 when nothing arrived within SECONDS.
"""

import json
import sys
import time

import rclpy
from rclpy.node import Node

from tests.ros.reference_messages import TYPES, make_reference, to_plain


def main() -> int:
    """Run the peer given by the command line."""
    role, type_name, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    msg_type = TYPES[type_name]
    rclpy.init()
    node = Node(f"test_{role}_{type_name.lower()}")
    topic = f"test_{type_name.lower()}"
    deadline = time.monotonic() + seconds
    received = []
    try:
        if role == "pub":
            pub = node.create_publisher(msg_type, topic, 10)
            msg = make_reference(type_name)
            while time.monotonic() < deadline:
                pub.publish(msg)
                rclpy.spin_once(node, timeout_sec=0.02)
            return 0
        node.create_subscription(msg_type, topic, received.append, 10)
        while not received and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        if not received:
            return 3
        sys.stdout.write(json.dumps(to_plain(received[0])) + "\n")
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
