"""A bag states the offered QoS of every clutch topic as the nodes offer it (issue 25).

The real publishing nodes run as processes (can_bridge with raw frames on, estimator,
controller, the demo's torque-request driver), then the real ``recorder`` records every
default topic. Compared, per topic, from the one table :data:`clutch_ros.interfaces.TOPICS`:

- the bag's ``metadata.yaml`` ``offered_qos_profiles`` (one per publisher, as ``ros2 bag
  record`` stores them) equal the table's publisher profile;
- what each publishing node really offers, from the ROS graph
  (``get_publishers_info_by_topic``), equals the table in everything DDS discovery carries
  (reliability, durability, liveliness, deadline, lifespan, lease); the history and depth it
  does not carry are checked against the node sources' own constants instead.
"""

import os
import subprocess
import sys

import pytest
import yaml

from clutch_ros import interfaces
from clutch_ros.cli.processes import NodeProcess, ros_param_args
from tests.nodes.rclpy_harness import Harness

#: [ns] RMW_DURATION_INFINITE as rmw reports it and rosbag2 stores it ({sec, nsec})
INFINITE_NS = 9223372036854775807
INFINITE = {"sec": 9223372036, "nsec": 854775807}

#: A stand-in for ``clutch demo``'s in-process torque-request publisher (DemoDriver).
DRIVER = """
import rclpy
from clutch_ros.nodes.demo_driver import DemoDriver
from clutch_ros.rig.request_profile import demo_profile
rclpy.init()
rclpy.spin(DemoDriver(demo_profile(1000.0, quick=True)))
"""


def _check_discovered(name: str, infos, spec) -> None:
    assert infos, f"no publisher of {name}"
    for info in infos:
        q = info.qos_profile
        assert q.reliability.name.lower() == spec.reliability, (name, info)
        assert q.durability.name.lower() == spec.durability, (name, info)
        assert q.liveliness.name.lower() == spec.liveliness, (name, info)
        for duration in (q.deadline, q.lifespan, q.liveliness_lease_duration):
            assert duration.nanoseconds in (0, INFINITE_NS), (name, info)  # default: infinite
        if q.history.name.lower() != "unknown":  # discovery does not carry the history
            assert (q.history.name.lower(), q.depth) == (spec.history, spec.depth), name


@pytest.mark.ros
@pytest.mark.slow
def test_recorded_offered_qos_is_what_the_nodes_offer(ros_env, tmp_path):
    logs = tmp_path / "logs"
    group = f"239.77.{os.getpid() % 250 + 1}.{os.getpid() // 250 % 250 + 1}"
    can = {"can.interface": "udp_multicast", "can.channel": group}
    publishers = [
        NodeProcess("can_bridge", ["--ros-args", *ros_param_args(
            {**can, "bridge.publish_raw": True})], ros_env, logs),
        NodeProcess("estimator", ["--ros-args"], ros_env, logs),
        NodeProcess("controller", ["--ros-args"], ros_env, logs),
    ]
    driver = subprocess.Popen([sys.executable, "-c", DRIVER], env=ros_env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    out = tmp_path / "bag"
    recorder = None
    discovered = {}
    try:
        with Harness("offered_qos") as h:
            def resolved(t):
                return h.node.resolve_topic_name(t.name)

            def missing():
                return [t.name for t in interfaces.TOPICS
                        if not h.node.count_publishers(resolved(t))]

            try:
                h.spin_until(lambda: not missing(), 90.0, "a publisher of every clutch topic")
            except AssertionError:
                tails = "\n".join(f"{p.name}: {p.tail(5)}" for p in publishers)
                raise AssertionError(f"no publisher of {missing()}; driver alive: "
                                     f"{driver.poll() is None}\n{tails}") from None
            h.spin_for(0.5)
            discovered = {t.absolute: h.node.get_publishers_info_by_topic(resolved(t))
                          for t in interfaces.TOPICS}
            recorder = NodeProcess("recorder", ["--ros-args", *ros_param_args(
                {"recorder.output": str(out), "recorder.discovery_wait": 10.0,
                 "recorder.drain_quiet": 0.5})], ros_env, logs)
            h.spin_until(lambda: "recording" in recorder.log_path.read_text()
                         or not recorder.alive(), 60.0, "the recorder to start")
            h.spin_for(1.0)
            assert recorder.alive(), recorder.tail()
        assert recorder.stop(timeout=30.0) == 0, recorder.tail()
    finally:
        driver.kill()
        driver.wait(timeout=10.0)
        for proc in [*publishers, *([recorder] if recorder else [])]:
            proc.stop()

    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    offered = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
               for t in meta["topics_with_message_count"]}
    assert set(offered) == {t.absolute for t in interfaces.TOPICS}
    for topic in interfaces.TOPICS:
        spec = topic.publisher
        _check_discovered(topic.absolute, discovered[topic.absolute], spec)
        profiles = offered[topic.absolute]
        assert profiles, f"{topic.absolute}: no offered QoS recorded"
        for qos in profiles:  # one per publisher the recorder saw, each as the table says
            assert {k: qos[k] for k in ("reliability", "durability", "history", "depth",
                                        "liveliness")} == {
                "reliability": spec.reliability, "durability": spec.durability,
                "history": spec.history, "depth": spec.depth,
                "liveliness": spec.liveliness}, (topic.absolute, qos)
            for key in ("deadline", "lifespan", "liveliness_lease_duration"):
                assert qos[key] == INFINITE, (topic.absolute, key, qos)
