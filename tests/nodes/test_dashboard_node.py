"""The live ``dashboard`` node (run as ``clutch dashboard``): ROS topics -> Foxglove, as bytes.

A test node publishes RigState (sensor-data QoS) and PressureCommand on ``pump_request`` over
DDS to the node in its own process; a WebSocket client of our own (``websockets``, not the
SDK) subscribes to those channels and to ``/diagnostics``. Every message must arrive, decode
with rosbags from the advertised schema to the values published and to the message a raw
rclpy subscription in the test receives (compared re-serialized: rclpy's
``serialize_message`` and different DDS paths fill alignment padding differently, so raw
bytes of two processes are no reference), and the node's own status must arrive on
/diagnostics.
"""

import asyncio
import re
import subprocess
import sys
import threading
import time

import pytest

from tests.cli.test_dashboard import free_port
from tests.conftest import REPO
from tests.dashboard.foxglove_client import FoxgloveClient
from tests.nodes.rclpy_harness import Harness, rig_state

pytestmark = pytest.mark.ros
N = 150


def canonical(client, topic, data):
    """Decode with the advertised schema and serialize again with rosbags."""
    typename = client.channels[topic]["schemaName"]
    msg = client.decode(topic, data)
    return client._stores[typename].serialize_cdr(msg, typename)


@pytest.fixture
def dashboard(ros_env):
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "clutch_ros.cli", "dashboard", "--port",
                             str(port)], cwd=REPO, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    ready = threading.Event()

    def pump():
        for line in proc.stdout:
            lines.append(line)
            if "Foxglove WebSocket server on" in line:
                ready.set()

    threading.Thread(target=pump, daemon=True).start()
    assert ready.wait(60), "".join(lines)
    assert re.search(rf"ws://127\.0\.0\.1:{port}\b", "".join(lines))
    yield f"ws://127.0.0.1:{port}"
    proc.send_signal(2)
    proc.wait(15)
    assert proc.returncode == 0, "".join(lines)


def test_live_topics_forwarded_as_ros_bytes(dashboard):
    from clutch_msgs.msg import PressureCommand, RigState
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    async def scenario(h):
        client = FoxgloveClient(dashboard)
        await client.connect()
        await client.subscribe(["/rig_state", "/pump_request", "/diagnostics"])
        ros_bytes = {"/rig_state": [], "/pump_request": []}
        h.node.create_subscription(RigState, "rig_state", ros_bytes["/rig_state"].append,
                                   QoSProfile(depth=1000,
                                              reliability=ReliabilityPolicy.BEST_EFFORT),
                                   raw=True)
        h.node.create_subscription(PressureCommand, "pump_request",
                                   ros_bytes["/pump_request"].append, reliable_qos(), raw=True)
        rig_pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
        cmd_pub = h.node.create_publisher(PressureCommand, "pump_request", reliable_qos())
        deadline = time.monotonic() + 30
        while rig_pub.get_subscription_count() < 2 or cmd_pub.get_subscription_count() < 2:
            assert time.monotonic() < deadline, "the dashboard node did not subscribe"
            await client.read_for(0.1)
        await client.read_for(0.5)
        sent = []
        t0 = time.time()
        for i in range(N):
            msg = rig_state(t0 + i * 0.01, pressure=1e5 * (i % 40))
            cmd = PressureCommand(pressure=1e5 * i, requested_torque=float(i), reason=f"n{i}")
            cmd.header.stamp = msg.header.stamp
            rig_pub.publish(msg)
            cmd_pub.publish(cmd)
            sent.append((msg, cmd))
            await client.read_for(0.01)
            h.executor.spin_once(timeout_sec=0.0)
        end = time.monotonic() + 1.5  # one more /diagnostics period
        while time.monotonic() < end:
            await client.read_for(0.01)
            h.executor.spin_once(timeout_sec=0.0)
        await client.close()
        return client, sent, ros_bytes

    with Harness() as h:
        client, sent, ros_bytes = asyncio.run(scenario(h))
    for topic, payloads in ros_bytes.items():
        got = [data for _, _, data in client.messages[topic]]
        assert len(got) == N, topic  # every message published reached the client
        # The same message as a raw subscription here receives (keyed by the header stamp,
        # bytes 4..12; compared canonically, re-serialized by rosbags: DDS paths may fill
        # alignment padding differently; rig_state samples the test's own best-effort
        # reader missed are not compared).
        by_stamp = {data[4:12]: data for data in got}
        assert len(by_stamp) == N
        assert len(payloads) >= N // 3, topic
        for data in payloads:
            assert canonical(client, topic, by_stamp[bytes(data[4:12])]) == canonical(
                client, topic, bytes(data)), topic
    for (msg, cmd), (_, _, rig_data), (_, _, cmd_data) in zip(
            sent, client.messages["/rig_state"], client.messages["/pump_request"]):
        rig = client.decode("/rig_state", rig_data)
        got_cmd = client.decode("/pump_request", cmd_data)
        assert (rig.header.stamp.sec, rig.header.stamp.nanosec) == (msg.header.stamp.sec,
                                                                     msg.header.stamp.nanosec)
        assert rig.actuating_pressure == msg.actuating_pressure
        assert (got_cmd.pressure, got_cmd.reason) == (cmd.pressure, cmd.reason)
    statuses = [client.decode("/diagnostics", d).status for _, _, d in
                client.messages["/diagnostics"]]
    ours = [s for array in statuses for s in array if s.name.endswith("/dashboard")]
    assert ours, "no status of the dashboard node on /diagnostics"
    values = {kv.key: kv.value for kv in ours[-1].values}
    assert int(values["forwarded_rig_state"]) == N and int(values["lost_rig_state"]) == 0
    assert int(values["clients"]) == 1
