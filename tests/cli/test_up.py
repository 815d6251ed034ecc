"""The launch files and ``clutch up``: static checks and the simulated chain in real processes.

Static: every ``<node>`` of ``launch/*.launch.xml`` names an executable ``setup.py`` installs
(as ``clutch_ros.nodes.<exec>:main``), every ``<param name>`` is a parameter that node
declares, and every parameter file loads. Live: ``clutch up launch/sim.launch.xml`` on a
private multicast group and ROS domain brings up rig_sim, can_bridge, estimator and
controller as processes; rig_state and clutch_estimate arrive over DDS in this process; a
SIGTERM stops every node and ``clutch up`` exits 0.
"""

import ast
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from clutch_ros.cli import up
from clutch_ros.config.launch_file import LaunchFileError, load_launch, parse_overrides
from clutch_ros.config.params_file import load_flat, load_params
from clutch_ros.nodes.model_params import model_param_specs
from tests.canbus.recorder import private_group
from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness

LAUNCH_FILES = sorted((REPO / "launch").glob("*.launch.xml"))
#: argument sets that together reach every node entry (rig: the recorder is conditional)
VARIANTS = {"sim.launch.xml": [{}], "rig.launch.xml": [{}, {"record": "true"}]}


def _setup_nodes() -> dict[str, str]:
    """Return setup.py's NODES table, read with ast (setup.py is not importable)."""
    tree = ast.parse((REPO / "setup.py").read_text())
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and getattr(stmt.targets[0], "id", "") == "NODES":
            return ast.literal_eval(stmt.value)
    raise AssertionError("setup.py has no NODES table")


def _descriptions():
    for path in LAUNCH_FILES:
        for overrides in VARIANTS[path.name]:
            yield path, load_launch(path, overrides)


def test_launch_files_exist_and_setup_installs_them():
    assert {p.name for p in LAUNCH_FILES} == set(VARIANTS)
    assert 'glob("launch/*.launch.xml")' in (REPO / "setup.py").read_text()


def test_every_node_entry_names_an_installed_executable():
    nodes = _setup_nodes()
    assert tuple(nodes) == up.NODE_EXECUTABLES
    seen = set()
    for path, desc in _descriptions():
        assert desc.nodes, path
        for node in desc.nodes:
            assert node.pkg == "clutch_ros", (path, node)
            assert nodes.get(node.executable) == f"clutch_ros.nodes.{node.executable}:main", \
                (path, node.executable)
            seen.add((path.name, node.executable))
    assert ("rig.launch.xml", "recorder") in seen  # record:=true reached the conditional node
    assert {e for f, e in seen if f == "sim.launch.xml"} == {
        "rig_sim", "can_bridge", "estimator", "controller"}


def test_every_parameter_is_declared_and_every_parameter_file_loads():
    for path, desc in _descriptions():
        for node in desc.nodes:
            module = __import__(f"clutch_ros.nodes.{node.executable}", fromlist=["PARAMS"])
            declared = {s.name for s in module.PARAMS} | {s.name for s in model_param_specs()}
            declared.add("use_sim_time")  # ROS's own, on every node (sim.launch.xml lockstep)
            for name, _ in node.params:
                assert name in declared, f"{path.name}: {node.executable} has no parameter {name}"
            for file in node.param_files:
                assert load_flat(file), file
                load_params(file)  # the model keys validate
            if node.executable == "rig_sim":
                rig_file = dict(node.params)["rig.params_file"]
                load_params(rig_file)


def test_arguments_substitute_into_the_command_lines(tmp_path):
    desc = load_launch(REPO / "launch" / "rig.launch.xml",
                       {"interface": "pcan", "channel": "PCAN_USBBUS1", "namespace": "/rig1"})
    bridge = next(n for n in desc.nodes if n.executable == "can_bridge")
    args = bridge.ros_args(tmp_path)
    assert args[:5] == ["--ros-args", "-r", "__node:=can_bridge", "-r", "__ns:=/rig1"]
    assert args[5::2] == ["--params-file"] * 5  # one file per <param>, as ros2 launch writes
    params = bridge.parameters()
    assert params["can.interface"] == "pcan" and params["can.channel"] == "PCAN_USBBUS1"
    assert load_flat(args[6], "/rig1/can_bridge") == {"can.interface": "pcan"}
    assert bridge.full_name == "/rig1/can_bridge"
    assert [n.executable for n in desc.nodes] == ["can_bridge", "estimator", "controller"]
    est = next(n for n in desc.nodes if n.executable == "estimator")
    assert Path(est.param_files[0]).resolve() == (REPO / "params" / "flexiforce_8.yaml")


@pytest.mark.parametrize(("text", "overrides", "message"), [
    ("<launch><arg name='a'/></launch>", {}, "argument a is required"),
    ("<launch><arg name='a' default='1'/></launch>", {"b": "2"}, "unknown argument(s) b"),
    ("<launch><executable cmd='ls'/></launch>", {}, "<executable>: unsupported element"),
    ("<launch><node pkg='clutch_ros' exec='estimator' respawn_max_retry='1'/></launch>", {},
     "unsupported attribute(s) respawn_max_retry"),
    ("<launch><node pkg='clutch_ros' exec='$(var nope)'/></launch>", {},
     "$(var nope): no launch argument or <let> named nope"),
    ("<launch><node pkg='clutch_ros' exec='$(command ls)'/></launch>", {},
     "unsupported substitution"),
    ("<launch><arg name='r' default='maybe'/>"
     "<node pkg='clutch_ros' exec='recorder' if='$(var r)'/></launch>", {},
     "if='maybe' is not true, false, 1 or 0"),
    ("<launch", {}, "not well-formed XML"),
])
def test_unsupported_or_bad_launch_files_are_refused(tmp_path, text, overrides, message):
    path = tmp_path / "x.launch.xml"
    path.write_text(text)
    with pytest.raises(LaunchFileError) as err:
        load_launch(path, overrides)
    assert message in str(err.value)


def test_bad_command_line_is_one_line_and_exit_2(tmp_path):
    assert parse_overrides(["a:=1", "b.c:=x:=y"]) == {"a": "1", "b.c": "x:=y"}
    cases = [(["up", "nope.launch.xml"], "no such launch file"),
             (["up", "sim.launch.xml", "channel=1"], "is not name:=value"),
             (["up", "sim.launch.xml", "params_file:=/no/such.yaml", "--print"],
              "parameter file /no/such.yaml not found")]
    for argv, text in cases:
        done = subprocess.run([sys.executable, "-m", "clutch_ros.cli", *argv], cwd=tmp_path,
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, (argv, done.stderr)
        assert done.stderr.count("\n") == 1 and text in done.stderr, (argv, done.stderr)


def _up_sim(tmp_path, ros_env, *options: str) -> subprocess.Popen:
    """Start ``clutch up sim.launch.xml`` on a private multicast group, logs in tmp_path."""
    group, port = private_group()
    cmd = [sys.executable, "-m", "clutch_ros.cli", "up", "sim.launch.xml", f"channel:={group}",
           f"port:={port}", *options, "--log-dir", str(tmp_path / "logs")]
    return subprocess.Popen(cmd, cwd=tmp_path, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _sigterm(proc: subprocess.Popen) -> str:
    """SIGTERM ``proc`` and wait for it (killed after 25 s); return its stderr."""
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.communicate(timeout=25)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()[1]


@pytest.mark.ros
def test_clutch_up_sim_brings_up_the_chain_and_stops_on_sigterm(tmp_path, ros_env):
    from clutch_msgs.msg import ClutchEstimate, RigState

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    proc = _up_sim(tmp_path, ros_env)
    try:
        with Harness("up_probe") as h:
            states = h.collect(RigState, "rig_state", sensor_qos())
            estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
            h.spin_until(lambda: len(states) >= 20 and len(estimates) >= 20, 25.0,
                         "rig_state and clutch_estimate from the launched chain")
    finally:
        err = _sigterm(proc)
    assert proc.returncode == 0, err
    pids = [int(p) for p in re.findall(r"pid (\d+)\)", err)]
    names = re.findall(r"started (\S+) \(", err)
    assert names == ["/rig_sim", "/can_bridge", "/estimator", "/controller"], err
    for pid in pids:  # every node process is gone (reaped by clutch up)
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert "all nodes stopped (exit code 0)" in err
    assert all(e.modelled_torque == e.modelled_torque for e in estimates)  # finite, not NaN
    assert {p.name for p in (tmp_path / "logs").glob("*.log")} == {
        "rig_sim.log", "can_bridge.log", "estimator.log", "controller.log"}


@pytest.mark.ros
def test_clutch_up_one_process_runs_the_chain_in_one_process(tmp_path, ros_env):
    """--one-process: bridge, estimator and controller in one process; SIGTERM stops all."""
    from clutch_msgs.msg import ClutchEstimate, PressureCommand

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    proc = _up_sim(tmp_path, ros_env, "--one-process")
    try:
        with Harness("up_one_probe") as h:
            estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
            commands = h.collect(PressureCommand, "pressure_command", sensor_qos())
            h.spin_until(lambda: len(estimates) >= 20 and len(commands) >= 5, 25.0,
                         "clutch_estimate and pressure_command from the one-process chain")
            # rig_sim reaches the chain over CAN, not DDS: on a loaded machine its participant
            # may be discovered after the chain's data flowed, so wait for the graph (bounded)
            expected = {"can_bridge", "estimator", "controller", "rig_sim"}

            def names_now() -> set:
                return {n for n, _ in h.node.get_node_names_and_namespaces()}

            h.spin_until(lambda: expected <= names_now(), 25.0, "the four nodes in the graph")
            names = names_now()
    finally:
        err = _sigterm(proc)
    assert proc.returncode == 0, err
    assert {"can_bridge", "estimator", "controller", "rig_sim"} <= names, names
    started = re.findall(r"started (\S+) \((\w+), pid (\d+)\)", err)
    assert [(n, e) for n, e, _ in started] == [
        ("/rig_sim", "rig_sim"), ("/can_bridge+/estimator+/controller", "composed")], err
    for _, _, pid in started:  # every process is gone (reaped by clutch up)
        with pytest.raises(ProcessLookupError):
            os.kill(int(pid), 0)
    assert "all nodes stopped (exit code 0)" in err
    assert all(e.modelled_torque == e.modelled_torque for e in estimates)  # finite, not NaN
    assert {p.name for p in (tmp_path / "logs").glob("*.log")} == {"rig_sim.log", "chain.log"}
    log = (tmp_path / "logs" / "chain.log").read_text()
    assert "Traceback" not in log, log


@pytest.mark.ros
def test_clutch_up_respawns_a_node_that_exits_after_its_delay(tmp_path, ros_env):
    """respawn/respawn_delay/respawn_max_retries: a player without a bag exits at once."""
    launch = tmp_path / "r.launch.xml"
    launch.write_text(
        "<launch><node pkg='clutch_ros' exec='bag_player' name='player' namespace='rig' "
        "respawn='true' respawn_delay='1.0' respawn_max_retries='2'>"
        f"<param name='player.bag' value='{tmp_path / 'no_such_bag'}'/></node></launch>")
    began = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "clutch_ros.cli", "up", str(launch),
                           "--log-dir", str(tmp_path / "logs")], cwd=tmp_path, env=ros_env,
                          capture_output=True, text=True, timeout=120)
    took = time.monotonic() - began
    assert done.returncode == 1, done.stderr  # the third exit ends the launch
    assert done.stderr.count("started /rig/player (bag_player") == 3, done.stderr
    assert done.stderr.count("node /rig/player exited with code") == 2, done.stderr
    assert done.stderr.count("respawning in 1 s") == 2, done.stderr
    assert took >= 2.0  # two respawn delays were waited (a lower bound holds under load)
    assert sorted(p.name for p in (tmp_path / "logs").glob("*.log")) == [
        "rig.player.2.log", "rig.player.3.log", "rig.player.log"]
    assert "no_such_bag" in (tmp_path / "logs" / "rig.player.2.log").read_text()


def test_launch_arguments_may_follow_the_options():
    """`clutch up FILE --print --json channel:=0`, as one writes `ros2 launch ... name:=value`."""
    import json

    from clutch_ros.cli.main import main as clutch

    def channels(*argv) -> dict:
        done = subprocess.run([sys.executable, "-m", "clutch_ros.cli", "up", "sim.launch.xml",
                               *argv], capture_output=True, text=True, cwd=REPO, timeout=60)
        assert done.returncode == 0, done.stderr
        return {n["name"]: n["parameters"]["can.channel"] for n in json.loads(done.stdout)
                if "can.channel" in n["parameters"]}

    after = channels("--print", "--json", "channel:=0")
    assert after == {"/rig_sim": 0, "/can_bridge": 0}
    assert channels("channel:=0", "--print", "--json") == after
    with pytest.raises(SystemExit) as err:  # anything else after the options is still refused
        clutch(["up", "sim.launch.xml", "--print", "bogus"])
    assert err.value.code == 2


def test_one_process_print_groups_the_chain_and_bad_composed_args_are_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-m", "clutch_ros.cli", "up", "sim.launch.xml",
                           "--one-process", "--print", "--json", "--log-dir", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    import json

    entries = json.loads(done.stdout)
    assert [e["executable"] for e in entries] == ["rig_sim", "composed"]
    chain = entries[1]
    assert chain["name"] == "/can_bridge+/estimator+/controller"
    assert [a for i, a in enumerate(chain["args"]) if chain["args"][i - 1] == "--node"] == [
        "can_bridge", "estimator", "controller"]
    assert chain["parameters"]["/can_bridge"]["can.interface"] == "udp_multicast"
    for argv, text in ((["--node", "recorder"], "--node recorder: not a composable node"),
                       (["-p", "x:=1"], "expected --node EXECUTABLE first")):
        bad = subprocess.run([sys.executable, "-m", "clutch_ros.nodes.composed", *argv],
                             capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
        assert text in bad.stderr, bad.stderr
