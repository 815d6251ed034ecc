"""``pump.rate_limit``, renamed ``pump.rise_rate_limit``: still accepted, with a deprecation WARN.

Three real can_bridge processes (``autostart:=false``: parameters only, no bus) are given the
old name in a YAML parameter file, as ``-p`` (an integer, as people type it), and in a YAML
file next to the new name on the command line. Read back over the parameter services, the
new parameter carries the old name's value (the new name wins when both are given); the old
name is not declared; a live set of the old name sets the new one. Each use logs a WARN
naming both. A wrong type or range under the old name fails the start as under the new one.
"""

import os

import pytest

from clutch_ros.cli.processes import NodeProcess, isolated_ros_env
from tests.nodes.rclpy_harness import Harness, assert_bad_settings_fail_at_start

pytestmark = pytest.mark.ros

OLD, NEW = "pump.rate_limit", "pump.rise_rate_limit"
WARNING = f"parameter {OLD} is deprecated, renamed {NEW}"


def _get(h, node, names):
    """Return the values of ``names`` on ``node`` (an empty list if one is not declared)."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    client = h.node.create_client(GetParameters, f"/{node}/get_parameters")
    values = h.call(client, GetParameters.Request(names=names)).values
    return [parameter_value_to_python(v) for v in values]


def test_old_rate_limit_name_is_accepted_with_a_warning(tmp_path):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    old_yaml = tmp_path / "old_name.yaml"
    old_yaml.write_text("/**:\n  ros__parameters:\n    pump:\n      rate_limit: 1.5e+6\n")
    env = isolated_ros_env(int(os.environ["ROS_DOMAIN_ID"]))
    cases = {  # node name -> extra ROS arguments
        "bridge_yaml": ["--params-file", str(old_yaml)],
        "bridge_cli": ["-p", f"{OLD}:=2500000"],
        "bridge_both": ["--params-file", str(old_yaml), "-p", f"{NEW}:=3.5e6"],
    }
    bridges = {name: NodeProcess(name, ["--ros-args", "-r", f"__node:={name}", "-p",
                                        "autostart:=false", *args], env, tmp_path / "logs",
                                 executable="can_bridge")
               for name, args in cases.items()}
    try:
        with Harness("renamed_params_test") as h:
            values = {name: _get(h, name, [NEW]) + _get(h, name, [OLD]) for name in bridges}
            setter = h.node.create_client(SetParameters, "/bridge_cli/set_parameters")
            live = h.call(setter, SetParameters.Request(parameters=[
                Parameter(OLD, value=7.5e5).to_parameter_msg()])).results[0]
            after = _get(h, "bridge_cli", [NEW])
            assert all(bridge.alive() for bridge in bridges.values())
    finally:
        codes = {name: bridge.stop() for name, bridge in bridges.items()}
    logs = {name: bridge.log_path.read_text() for name, bridge in bridges.items()}
    assert codes == dict.fromkeys(bridges, 0), (codes, logs)
    # the old name's value is the new parameter's; the new name wins; the old is not declared
    # (get_parameters answers nothing for an undeclared name)
    assert values == {"bridge_yaml": [1.5e6], "bridge_cli": [2.5e6], "bridge_both": [3.5e6]}, \
        values
    assert live.successful, live.reason
    assert after == [7.5e5]
    # one WARN per use, naming both names
    for name, log in logs.items():
        lines = [line for line in log.splitlines() if WARNING in line]
        assert all("WARN" in line for line in lines), lines
        assert len(lines) == (2 if name == "bridge_cli" else 1), (name, log)
    assert "1500000.0" in logs["bridge_yaml"] and "2500000.0" in logs["bridge_cli"]
    assert "ignored" in logs["bridge_both"] and "3500000.0" in logs["bridge_both"]
    assert f"setting {NEW}=750000.0" in logs["bridge_cli"]


def test_old_rate_limit_name_is_checked_as_the_new_one(ros_env):
    """A wrong type or an out-of-range value under the old name stops the node with one line."""
    assert_bad_settings_fail_at_start("can_bridge", {
        "type": (["-p", f"{OLD}:=fast"], f"{OLD} (deprecated, renamed {NEW}) must be a float"),
        "range": (["-p", f"{OLD}:=1e12"], NEW),
    }, ros_env)
