"""Every value a launch argument's description lists works, integer-looking channels included.

``ros2 launch`` and ``clutch up`` hand a ``<param value=...>`` to ROS as YAML, as ``-p`` does:
``channel:=0`` reaches ``can.channel`` as the integer 0 (a Vector or Kvaser channel), which
the nodes accept (``can.channel`` is dynamically typed). For each argument value listed in a
description of ``launch/*.launch.xml`` (:data:`LISTED`, kept equal to the descriptions), the
file is read with that value as ``clutch up`` reads it, and each of its nodes is created in
this process from the resulting ``--ros-args`` (rclpy parses them as in the node's process)
and declares its parameters: none is refused, and the values arrive with the expected type.
One bridge runs as a real process on ``rig.launch.xml interface:=virtual channel:=0``.
"""

from __future__ import annotations

import re

import pytest

from clutch_ros.config.launch_file import load_launch
from tests.conftest import REPO

pytestmark = pytest.mark.ros

#: (launch file, argument) -> the values its description lists
LISTED = {
    ("rig.launch.xml", "namespace"): ["/rig1"],
    ("rig.launch.xml", "interface"): ["socketcan", "pcan", "vector", "kvaser"],
    ("rig.launch.xml", "channel"): ["can0", "PCAN_USBBUS1", "0"],
    ("rig.launch.xml", "bitrate"): ["0"],
    ("rig.launch.xml", "record"): ["true", "false"],
    ("rig.launch.xml", "bag"): ["''"],
    ("sim.launch.xml", "namespace"): ["/rig1"],
    ("sim.launch.xml", "channel"): ["0"],
}
#: what ROS makes of a value given as text (YAML, as ``-p`` and launch_ros read it)
TYPED = {"0": 0, "''": "", "true": True, "false": False}


def _description(path, name: str) -> str:
    text = path.read_text()
    match = re.search(rf'<arg name="{name}"[^>]*description="([^"]*)"', text, re.S)
    assert match, (path.name, name)
    return match.group(1)


def test_the_table_lists_what_the_descriptions_list():
    for (file, name), values in LISTED.items():
        description = _description(REPO / "launch" / file, name)
        for value in values:
            assert value in description, (file, name, value, description)
    for file in ("rig.launch.xml", "sim.launch.xml"):
        assert "0" in _description(REPO / "launch" / file, "channel")  # numbered channels


def _declared_values(entry, context) -> dict:
    """Create ``entry``'s node from its ros args in ``context``; return its declared values."""
    from rclpy.node import Node

    from clutch_ros.nodes.parameters import declare_params

    module = __import__(f"clutch_ros.nodes.{entry.executable}", fromlist=["PARAMS"])
    node = Node(entry.executable, context=context)
    try:
        return declare_params(node, module.PARAMS)
    finally:
        node.destroy_node()


@pytest.mark.parametrize(("file", "name", "value"), [
    (file, name, value) for (file, name), values in LISTED.items() for value in values])
def test_each_listed_value_is_accepted_by_every_node(file, name, value, tmp_path):
    import rclpy
    from rclpy.context import Context

    overrides = {name: value}
    if file == "rig.launch.xml" and name != "record":
        overrides["record"] = "true"  # the recorder's parameters too
    desc = load_launch(REPO / "launch" / file, overrides)
    assert desc.nodes
    for entry in desc.nodes:
        context = Context()
        rclpy.init(args=["launch_value_test", *entry.ros_args(tmp_path)], context=context)
        try:
            values = _declared_values(entry, context)
        finally:
            rclpy.try_shutdown(context=context)
        for param, _ in entry.params:
            source = _param_source(file, entry.executable, param)
            if source == f"$(var {name})":  # the value itself, typed as YAML
                want = TYPED.get(value, value)
                got = values[param]
                assert got == want and type(got) is type(want), (entry.executable, param, got)
            elif f"$(var {name})" in source:  # inside a text, e.g. interface:channel
                assert value in values[param], (entry.executable, param, values[param])
    executables = [entry.executable for entry in desc.nodes]
    if name == "record":
        assert ("recorder" in executables) == (value == "true"), executables
    if name == "namespace":
        assert {entry.namespace for entry in desc.nodes} == {value}


def _param_source(file: str, executable: str, param: str) -> str:
    """Return the raw ``value`` attribute of ``param`` in ``executable``'s ``<node>``."""
    text = (REPO / "launch" / file).read_text()
    node = re.search(rf'<node [^>]*exec="{executable}".*?</node>', text, re.S)
    assert node, (file, executable)
    match = re.search(rf'<param name="{re.escape(param)}" value="([^"]*)"', node.group(0))
    return match.group(1) if match else ""


def test_a_numbered_channel_runs_the_bridge_as_the_rig_launch_file_starts_it(ros_env, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    from tests.nodes.rclpy_harness import Harness, node_process

    desc = load_launch(REPO / "launch" / "rig.launch.xml",
                       {"interface": "virtual", "channel": "0"})
    bridge = next(n for n in desc.nodes if n.executable == "can_bridge")
    assert ("can.channel", 0) in bridge.params  # an int, as ros2 launch types value="0"
    with node_process("can_bridge", ros_env, *bridge.ros_args(tmp_path)[1:]) as proc, \
            Harness("launch_channel_test") as h:
        diags = h.collect(DiagnosticArray, "/diagnostics", 50)

        def link() -> str:
            for array in reversed(diags):
                for status in array.status:
                    if status.name == "/can_bridge":
                        return {kv.key: kv.value for kv in status.values}.get("link_state", "")
            return ""

        h.spin_until(lambda: link() == "up" or proc.poll() is not None, 60.0,
                     "the bridge's link on virtual channel 0")
        assert proc.poll() is None, "can_bridge exited"
        assert link() == "up"
