"""The launch-file reader of ``clutch up`` against what the real ``ros2 launch`` gives each node.

``data/expected_real_launch.json`` holds, per test launch file and node, the command line and
the resulting parameters that ros2/launch + launch_ros produced (how: its ``_how_obtained``).
``clutch up --print --json`` must give every node the same name, namespace, arguments,
parameter sources in the same order, the same resulting parameters and the same remappings;
a node launch respawned must be a respawning node here, with the delay launch waited.
"""

import json
import subprocess
import sys

import pytest
import yaml

from clutch_ros.config.launch_file import LaunchFileError, load_launch, package_share
from tests.conftest import REPO

DATA = REPO / "tests" / "config" / "data"
EXPECTED = json.loads((DATA / "expected_real_launch.json").read_text())["cases"]


def _clean(value):
    """Write absolute paths as the expected data does."""
    if isinstance(value, str):
        return value.replace(str(DATA.resolve()), "$(dirname)") \
            .replace(str(package_share()), "$(find-pkg-share clutch_ros)")
    return value


def _clutch_print(name: str, log_dir) -> dict[str, dict]:
    done = subprocess.run([sys.executable, "-m", "clutch_ros.cli", "up", str(DATA / name),
                           "--print", "--json", "--log-dir", str(log_dir)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return {n["name"]: n for n in json.loads(done.stdout)}


def _sources(ros_args: list[str]) -> tuple[list, list]:
    """Split a ROS block into parameter sources (in order) and -r remappings.

    A parameter file written for one ``<param>`` (launch's ``<launch_params_file>``, or
    clutch's file in its parameter directory) is compared by content: section and values.
    """
    sources, remaps = [], []
    for flag, value in zip(ros_args[::2], ros_args[1::2], strict=True):
        if flag == "<launch_params_file>":
            sources.append(("values", yaml.safe_load(value)))
        elif flag == "--params-file" and "/logs/params/" in value:  # clutch's, see below
            sources.append(("values", yaml.safe_load(open(value).read())))
        elif flag == "--params-file":
            sources.append(("file", _clean(value)))
        else:
            assert flag == "-r", flag
            remaps.append(value)
    return sources, remaps


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_clutch_up_print_gives_each_node_what_ros2_launch_gives(name, tmp_path):
    expected = EXPECTED[name]
    got = _clutch_print(name, tmp_path / "logs")
    assert sorted(got) == sorted(expected)
    for full_name, real in expected.items():
        node = got[full_name]
        assert node["executable"] == real["exe"], full_name
        last = len(node["args"]) - node["args"][::-1].index("--ros-args")
        sources, remaps = _sources(node["args"][last:])
        real_sources, real_remaps = _sources(real["ros_args"])
        assert node["args"][:last] == real["head"], full_name
        assert sources == real_sources, full_name  # same files and sections, same order
        assert remaps == real_remaps, full_name  # __node, __ns, then <remap>s
        params = {k: _clean(v) for k, v in node["parameters"].items()}
        assert params == real["parameters"], full_name
        assert node["respawn"] == (real["starts"] > 1), full_name
        for gap in real["start_gaps_s"]:  # start to start: the node's run + respawn_delay
            assert node["respawn_delay"] <= gap, full_name


def test_the_cases_cover_the_issue():
    """Group/push-ros-namespace, two includes, respawn, document order, typed values."""
    group = EXPECTED["group_ns.launch.xml"]
    assert {"/rigA/est", "/rigA/sub/inner/ctl", "/abs/rec", "/rigA/sub/player"} <= set(group)
    est = group["/rigA/est"]["parameters"]
    # rcl keeps a table per section, in first-appearance order: /rigA/est (the first
    # <param>, later ones and the file's /rigA/est section), then the file's /**, which wins
    assert est["estimator.window"] == 40 and est["diagnostics.hardware_id"] == "from-file"
    assert est["can.channel"] == 0 and est["can.channel_text"] == "0"
    includes = EXPECTED["two_includes.launch.xml"]
    assert {"/left/bridge", "/left/controller", "/right/bridge"} <= set(includes)
    assert "/right/controller" not in includes
    respawned = EXPECTED["respawn.launch.xml"]["/rig/est"]
    assert respawned["starts"] >= 3 and respawned["head"][:2] == ["--extra", "1"]


def test_values_scope_like_launch():
    desc = load_launch(DATA / "two_includes.launch.xml", {"rate": "20"})
    rates = {n.full_name: n.parameters().get("bridge.rate") for n in desc.nodes}
    assert rates["/left/bridge"] == 20  # the top-level value beats the included default
    assert rates["/right/bridge"] == 200  # the <include>'s <arg> "$(var rate)0"
    assert desc.values["last_prefix"] == "right"  # an include is not a scope


@pytest.mark.parametrize(("text", "message"), [
    ("<launch><arg name='a'/></launch>", "x.launch.xml:1: <arg>: argument a is required"),
    ("<launch>\n<set_parameter name='a' value='1'/></launch>",
     "x.launch.xml:2: <set_parameter>: unsupported element"),
    ("<launch><group forwarding='false'/></launch>", "forwarding=\"false\" is not supported"),
    ("<launch><group><push-ros-namespace ns='a'/></group></launch>",
     "<push-ros-namespace>: unsupported attribute(s) ns"),
    ("<launch><include file='$(dirname)/x.launch.py'/></launch>", "only XML launch files"),
    ("<launch><include file='/no/such.launch.xml'/></launch>", "not found"),
    ("<launch><include file='$(filename)'/></launch>", "nested deeper than 20"),
    ("<launch><include file='$(dirname)/y.launch.xml'><let name='a' value='1'/></include>"
     "</launch>", "<let>: unsupported element inside <include>"),
    ("<launch><node pkg='clutch_ros' exec='estimator' respawn_delay='$(env D 1)'/></launch>",
     "respawn_delay takes a plain number"),
    ("<launch><node pkg='clutch_ros' exec='estimator' respawn='maybe'/></launch>",
     "respawn='maybe' is not true, false, 1 or 0"),
    ("<launch><node pkg='clutch_ros' exec='estimator' launch-prefix='gdb'/></launch>",
     "unsupported attribute(s) launch-prefix"),
    ("<launch><node pkg='clutch_ros' exec='estimator'>\n<env name='A' value='1'/></node>"
     "</launch>", "x.launch.xml:2: <env>: unsupported element inside <node>"),
    ("<launch><node pkg='clutch_ros' exec='estimator'><param name='a' value='{b: 1}'/>"
     "</node></launch>", "neither a scalar nor a non-empty list"),
    ("<launch><node pkg='clutch_ros' exec='estimator'><param name='a' value='x' type='ints'/>"
     "</node></launch>", "type='ints' is not supported"),
    ("<launch><node pkg='clutch_ros' exec='$(eval 1)'/></launch>",
     "unsupported substitution $(eval ...)"),
    ("<launch><node pkg='clutch_ros' exec='$(var a'/></launch>", "unclosed substitution"),
])
def test_unsupported_or_bad_elements_are_named(tmp_path, text, message):
    path = tmp_path / "x.launch.xml"
    path.write_text(text)
    (tmp_path / "y.launch.xml").write_text("<launch/>")
    (tmp_path / "x.launch.py").write_text("")
    with pytest.raises(LaunchFileError) as err:
        load_launch(path)
    assert message in str(err.value)


def test_substitutions_quote_nest_and_find_files(tmp_path, monkeypatch):
    monkeypatch.setenv("CLUTCH_TEST_WHICH", "b")
    monkeypatch.delenv("CLUTCH_TEST_UNSET", raising=False)
    path = tmp_path / "x.launch.xml"
    path.write_text(
        "<launch><let name='b' value='bee'/>"
        "<node pkg='clutch_ros' exec='estimator' name=\"n$(optenv CLUTCH_TEST_UNSET)\">"
        "<param name='p' value=\"$(var $(env CLUTCH_TEST_WHICH))\"/>"
        "<param name='q' value=\"$(env CLUTCH_TEST_UNSET 'a b')\"/>"
        "<param name='d' value='$(dirname)'/></node></launch>")
    node = load_launch(path).nodes[0]
    assert node.name == "n"
    assert node.params == [("p", "bee"), ("q", "a b"), ("d", str(tmp_path.resolve()))]


def test_relative_include_is_relative_to_the_working_directory_and_groups_take_if(
        tmp_path, monkeypatch):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "inner.launch.xml").write_text(
        "<launch><arg name='ns'/><group if='$(var on)'><push-ros-namespace namespace='$(var ns)'/>"
        "<node pkg='clutch_ros' exec='estimator' name='e'/></group></launch>")
    top = tmp_path / "sub" / "top.launch.xml"
    top.write_text("<launch><arg name='on' default='1'/>"
                   "<include file='sub/inner.launch.xml'><arg name='ns' value='a'/></include>"
                   "</launch>")
    monkeypatch.chdir(tmp_path)
    assert [n.full_name for n in load_launch(top).nodes] == ["/a/e"]
    assert load_launch(top, {"on": "0"}).nodes == []
    missing = tmp_path / "sub" / "missing.launch.xml"  # ns set, but not by the <include>
    missing.write_text("<launch><let name='ns' value='b'/><arg name='on' default='1'/>"
                       "<include file='sub/inner.launch.xml'/></launch>")
    with pytest.raises(LaunchFileError, match="requires argument ns: give it as <arg>"):
        load_launch(missing)
    monkeypatch.chdir(tmp_path / "sub")  # the same relative path now names nothing
    with pytest.raises(LaunchFileError, match="included launch file sub/inner.launch.xml"):
        load_launch(top)


@pytest.mark.ros
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_rcl_reads_clutch_up_arguments_as_the_parameters_ros2_launch_gives(name, tmp_path):
    """The last mile: rcl itself parses clutch's -p/--params-file into the same values."""
    import rclpy
    from rclpy.node import Node

    got = _clutch_print(name, tmp_path / "logs")
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        for full_name, real in EXPECTED[name].items():
            node = Node(got[full_name]["executable"], context=context,
                        cli_args=got[full_name]["args"],
                        automatically_declare_parameters_from_overrides=True,
                        start_parameter_services=False)
            try:
                assert node.get_fully_qualified_name() == full_name
                values = {p: node.get_parameter(p).value for p in node._parameters
                          if p not in ("use_sim_time", "start_type_description_service")}
            finally:
                node.destroy_node()
            values = {k: list(v) if not isinstance(v, (str, bool, int, float)) else _clean(v)
                      for k, v in values.items()}
            assert values == real["parameters"], full_name
    finally:
        rclpy.shutdown(context=context)
