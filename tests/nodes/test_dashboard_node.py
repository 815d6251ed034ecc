"""The live ``dashboard`` node (run as ``clutch dashboard``): ROS topics -> Foxglove, as bytes.

A test node publishes RigState (sensor-data QoS) and PressureCommand on ``pump_request`` over
DDS to the node in its own process; a WebSocket client of our own (``websockets``, not the
SDK) subscribes to those channels and to ``/diagnostics``. Every message must arrive, decode
with rosbags from the advertised schema to the values published and to the message a raw
rclpy subscription in the test receives (compared re-serialized: rclpy's
``serialize_message`` and different DDS paths fill alignment padding differently, so raw
bytes of two processes are no reference), and the node's own status must arrive on
/diagnostics.

Issue 26: against a live chain (estimator and controller processes) the client gets and sets
the estimator's parameters (an out-of-range value comes back refused with the node's own
reason; a change made with ``ros2 param set`` reaches a subscribed client), publishes torque
requests (cdr and json) the controller answers, and is refused on any other topic; the
server's time is the node clock, sim time under ``use_sim_time``.
"""

import asyncio
import re
import time

import pytest

from tests.dashboard.command import dashboard_command
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
    with dashboard_command(env=ros_env, ready="Foxglove WebSocket server on") as (url, lines):
        assert re.search(rf"{url}\b", "".join(lines))
        yield url


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


@pytest.fixture
def live_chain(ros_env):
    """Estimator and controller processes, and ``clutch dashboard --allow-publish``."""
    from tests.nodes.rclpy_harness import node_process

    with node_process("estimator", ros_env), node_process("controller", ros_env), \
            dashboard_command("--allow-publish", env=ros_env,
                              ready="Foxglove WebSocket server on") as (url, lines):
        assert "clients may publish on /torque_request" in "".join(lines)
        yield url


def test_live_time_parameters_and_client_publish(live_chain):
    from clutch_msgs.msg import PressureCommand
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from clutch_ros.bag.typestore import clutch_typestore, torque_request_msg
    from clutch_ros.config.params_file import load_params
    from clutch_ros.config.presets import preset_path
    from clutch_ros.nodes.qos import reliable_qos

    bad = "estimator.input_timeout"  # range 0.001 .. 3600 s

    async def scenario(h):
        commands = h.collect(PressureCommand, "pressure_command", reliable_qos())
        direct = h.node.create_client(SetParameters, "/estimator/set_parameters")
        request = SetParameters.Request(parameters=[Parameter(bad, value=-1.0).to_parameter_msg()])
        reason = h.call(direct, request).results[0].reason
        c = FoxgloveClient(live_chain)
        await c.connect()
        names = [f"/estimator.{k}" for k in ("spline.law", "clutch.lamella_count",
                                             "friction.mu_ref", bad)]
        # The dashboard finds the nodes within a second or two: ask until they answer.
        deadline = time.monotonic() + 30
        while not any(len(m["parameters"]) == len(names) for m in c.parameter_values):
            assert time.monotonic() < deadline, c.statuses
            await c.send_json(op="getParameters", parameterNames=names, id="get")
            await c.read_for(1.0)
        await c.send_json(op="setParameters", id="set", parameters=[
            {"name": f"/estimator.{bad}", "value": -1.0, "type": "float64"}])
        await c.wait_for(lambda: any(bad in s["message"] for s in c.statuses), 10, "refusal")
        # Publishing: CDR and JSON on /torque_request reach the controller; any other topic
        # is refused with a status message.
        schema = c.channels["/torque_request"]["schema"]
        await c.advertise(1, "/torque_request", "cdr", "clutch_msgs/msg/TorqueRequest", schema)
        await c.advertise(2, "/torque_request", "json", "clutch_msgs/msg/TorqueRequest")
        await c.advertise(3, "/pressure_command", "cdr", "clutch_msgs/msg/PressureCommand",
                          c.channels["/pressure_command"]["schema"])
        cdr = bytes(clutch_typestore().serialize_cdr(torque_request_msg(0, 123.0),
                                                     "clutch_msgs/msg/TorqueRequest"))
        end = time.monotonic() + 30
        while h.node.count_subscribers("torque_request") < 1 or not commands:
            assert time.monotonic() < end, "the controller did not start"
            await c.read_for(0.05)
            h.executor.spin_once(timeout_sec=0.0)
        for channel, payload, torque in ((1, cdr, 123.0), (2, b'{"torque": 77.0}', 77.0)):
            # sent again each second: a request published before the dashboard's publisher
            # matched the controller's subscription is lost, as for any volatile publisher
            end = time.monotonic() + 15
            sent = 0.0
            while not any(m.requested_torque == torque for m in commands):
                assert time.monotonic() < end, f"the controller did not get {torque} N m"
                if time.monotonic() - sent > 1.0:
                    await c.publish(channel, payload)
                    sent = time.monotonic()
                await c.read_for(0.05)
                h.executor.spin_once(timeout_sec=0.0)
        await c.publish(3, cdr)
        await c.read_for(1.0)
        # A valid set applies; a change made by anyone reaches a subscribed client.
        await c.send_json(op="setParameters", id="set2", parameters=[
            {"name": "/estimator.estimator.max_gap", "value": 1.5, "type": "float64"}])
        await c.send_json(op="subscribeParameterUpdates",
                          parameterNames=["/estimator.estimator.max_gap"])
        await c.wait_for(lambda: any(m.get("id") == "set2" for m in c.parameter_values), 10,
                         "the set answer")
        await c.read_for(0.5)
        request = SetParameters.Request(
            parameters=[Parameter("estimator.max_gap", value=2.5).to_parameter_msg()])
        assert h.call(direct, request).results[0].successful
        await c.wait_for(lambda: any("id" not in m and m["parameters"][0]["value"] == 2.5
                                     for m in c.parameter_values), 10, "the update")
        await c.close()
        return c, reason, commands

    with Harness() as h:
        c, reason, commands = asyncio.run(scenario(h))
    assert {"time", "parameters", "clientPublish"} <= set(c.server_info["capabilities"])
    assert {"cdr", "json"} <= set(c.server_info["supportedEncodings"])
    assert "playbackControl" not in c.server_info["capabilities"]
    # time: the node clock (system time here), as the log times are
    assert len(c.times) >= 10
    assert all(abs(t - (time.time_ns() - (time.monotonic() - wall) * 1e9)) < 0.5e9
               for wall, t in c.times)
    flat = load_params(preset_path("flexiforce_8")).to_flat()
    got = next(m for m in c.parameter_values if len(m["parameters"]) == 4)["parameters"]
    values = {p["name"]: p["value"] for p in got}
    assert values["/estimator.spline.law"] == flat["spline.law"]
    assert values["/estimator.clutch.lamella_count"] == flat["clutch.lamella_count"]
    assert values["/estimator.friction.mu_ref"] == pytest.approx(flat["friction.mu_ref"])
    assert values[f"/estimator.{bad}"] == pytest.approx(0.5)
    assert reason
    refusal = next(s for s in c.statuses if bad in s["message"])
    assert refusal["message"] == f"/estimator.{bad}: {reason}" and refusal["level"] == 1
    answer = next(m for m in c.parameter_values if m.get("id") == "set")["parameters"]
    assert answer == [{"name": f"/estimator.{bad}", "value": 0.5, "type": "float64"}]
    refused = [s["message"] for s in c.statuses if "/pressure_command" in s["message"]]
    assert refused and "refused" in refused[0] and "/torque_request" in refused[0]
    assert any("channel 3 refused" in s["message"] for s in c.statuses)
    stamped = next(m for m in commands if m.requested_torque == 123.0)
    assert stamped.header.stamp.sec > 0
    answer = next(m for m in c.parameter_values if m.get("id") == "set2")["parameters"]
    assert answer == [{"name": "/estimator.estimator.max_gap", "value": 1.5, "type": "float64"}]


def test_live_time_is_sim_time_under_use_sim_time(ros_env):
    from rosgraph_msgs.msg import Clock

    from tests.dashboard.command import free_port
    from tests.nodes.rclpy_harness import node_process

    port = free_port()
    url = f"ws://127.0.0.1:{port}"
    sim0 = 1000

    async def scenario(h):
        pub = h.node.create_publisher(Clock, "/clock", 10)
        c = FoxgloveClient(url)
        deadline = time.monotonic() + 60
        while True:
            try:
                await c.connect()
                break
            except OSError:
                assert time.monotonic() < deadline, "the dashboard node did not start"
                await asyncio.sleep(0.5)
        await c.read_for(0.5)
        assert not c.times  # no time before the first /clock
        # /clock steps 0.1 s of sim time every 0.05 s of wall time until the node has sent
        # time for a second (its /clock subscription matches our publisher after discovery)
        i = 0
        deadline = time.monotonic() + 60
        while len(c.times) < 20:
            assert time.monotonic() < deadline and i < 9000, "no time messages"
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = sim0 + i // 10, (i % 10) * 100_000_000
            pub.publish(msg)
            h.executor.spin_once(timeout_sec=0.0)
            await c.read_for(0.05)
            i += 1
        await c.close()
        return c, sim0 * 10**9 + i * 100_000_000

    with node_process("dashboard", ros_env, "-p", "use_sim_time:=true", "-p",
                      f"dashboard.port:={port}"), Harness() as h:
        c, last_ns = asyncio.run(scenario(h))
    assert "time" in c.server_info["capabilities"]
    # every time sent is a sim time we published (not the wall clock), and it moves on
    assert all(sim0 * 10**9 <= t <= last_ns for _, t in c.times), (c.times[:3], last_ns)
    assert c.times[-1][1] - c.times[0][1] >= 500_000_000
