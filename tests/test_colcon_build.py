"""The package builds with colcon on a rig PC layout and every node answers ``--help``.

This is the proof that ``colcon build --paths src/clutch_ros src/clutch_ros/msg_defs`` and
``ros2 run clutch_ros <node>`` work: colcon (colcon-core + colcon-ros from the package index)
builds both packages into a temporary workspace (a plain build: copies, no
``--symlink-install``); each executable in ``install/clutch_ros/lib/clutch_ros/`` is then
started from a shell that sourced ``install/setup.sh``, exactly as ``ros2 run`` would find and
start it. The installed package finds its data (DBC, presets, dashboard layout) in
``install/clutch_ros/share/clutch_ros`` through the ament index, while Python's ``sys.prefix``
is elsewhere (this venv; ``/usr`` on a rig PC): ``rig_sim`` and ``can_bridge`` start from the
install on their default DBC and stop with exit 0 on SIGINT.
"""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO

NODES = ["can_bridge", "rig_sim", "estimator", "controller", "recorder", "bag_player"]
VENV = Path(sys.prefix)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """Copy the source tree into ws/src/clutch_ros and colcon-build it; return ws."""
    ws = tmp_path_factory.mktemp("ws")
    src = ws / "src" / "clutch_ros"
    ignore = shutil.ignore_patterns(".venv", ".git", "build", "install", "log", "__pycache__",
                                    "*.egg-info", ".ruff_cache")
    shutil.copytree(REPO, src, ignore=ignore)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(VENV), CMAKE_PREFIX_PATH=str(VENV))
    cmd = [str(VENV / "bin" / "colcon"), "build", "--paths", "src/clutch_ros",
           "src/clutch_ros/msg_defs", "--cmake-args", f"-DPython3_EXECUTABLE={sys.executable}",
           "-DBUILD_TESTING=OFF"]
    done = subprocess.run(cmd, cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, \
        f"colcon build failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return ws


def _sourced(workspace, command: str) -> tuple[list[str], dict]:
    """Return (argv, env) running ``command`` in bash after sourcing the install, from ``/``."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["AMENT_PREFIX_PATH"] = str(VENV)
    return ["bash", "-c", f". '{workspace}/install/setup.sh' && cd / && {command}"], env


def test_both_packages_installed(workspace):
    assert (workspace / "install" / "clutch_msgs" / "share" / "clutch_msgs" / "msg"
            / "RigState.msg").is_file()
    share = workspace / "install" / "clutch_ros" / "share" / "clutch_ros"
    assert (share / "package.xml").is_file()
    assert (share / "params" / "rig.dbc").is_file()
    assert list((share / "params").glob("*.yaml")), "no parameter presets installed"
    launch = sorted(p.name for p in (share / "launch").glob("*.launch.xml"))
    assert launch == ["rig.launch.xml", "sim.launch.xml"], launch
    assert (workspace / "install" / "clutch_msgs" / "share" / "clutch_msgs" / "srv"
            / "SetPaused.srv").is_file()
    marker = (workspace / "install" / "clutch_ros" / "share" / "ament_index"
              / "resource_index" / "packages" / "clutch_ros")
    assert marker.is_file()


@pytest.mark.parametrize("node", NODES)
def test_node_executable_answers_help(workspace, node):
    exe = workspace / "install" / "clutch_ros" / "lib" / "clutch_ros" / node
    assert exe.is_file() and os.access(exe, os.X_OK), f"{exe} missing or not executable"
    argv, env = _sourced(workspace, f"'{exe}' --help")
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"{node} --help failed:\n{done.stdout}\n{done.stderr}"
    assert node in done.stdout and "--ros-args" in done.stdout


def test_installed_package_is_the_one_imported(workspace):
    probe = ("import clutch_ros, clutch_msgs; print(clutch_ros.__file__); "
             "print(clutch_msgs.__file__)")
    argv, env = _sourced(workspace, f"'{sys.executable}' -c '{probe}'")
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    ros_file, msgs_file = done.stdout.split()
    assert ros_file.startswith(str(workspace / "install" / "clutch_ros")), ros_file
    assert msgs_file.startswith(str(workspace / "install" / "clutch_msgs")), msgs_file


def test_installed_data_is_found_through_the_ament_index(workspace):
    share = workspace / "install" / "clutch_ros" / "share" / "clutch_ros"
    probe = ("import sys; from clutch_ros.canbus.dbc import default_dbc_path; "
             "from clutch_ros.config.presets import LAYOUT_NAME, preset_path, share_file; "
             "print(sys.prefix); print(default_dbc_path()); print(preset_path('rig_truth')); "
             "print(share_file(LAYOUT_NAME))")
    argv, env = _sourced(workspace, f"'{sys.executable}' -c \"{probe}\"")
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    prefix, dbc, preset, layout = done.stdout.split()
    assert not Path(prefix).is_relative_to(workspace), prefix  # sys.prefix is not the install
    assert Path(dbc) == share / "params" / "rig.dbc" and Path(dbc).is_file()
    assert Path(preset) == share / "params" / "rig_truth.yaml" and Path(preset).is_file()
    assert Path(layout) == share / "params" / "clutch_dashboard.json" and Path(layout).is_file()


@pytest.mark.ros
@pytest.mark.parametrize(("node", "started"), [("rig_sim", "simulated rig running"),
                                               ("can_bridge", "open; decoding with")])
def test_installed_node_starts_on_the_installed_dbc(workspace, node, started):
    """The node of the plain install loads share/clutch_ros/params/rig.dbc, runs, stops 0."""
    exe = workspace / "install" / "clutch_ros" / "lib" / "clutch_ros" / node
    dbc = workspace / "install" / "clutch_ros" / "share" / "clutch_ros" / "params" / "rig.dbc"
    log = workspace / f"{node}.log"
    argv, env = _sourced(workspace, f"exec '{exe}' --ros-args -p can.interface:=virtual "
                                    "-p can.channel:=colcon_test")
    with open(log, "w") as out:
        proc = subprocess.Popen(argv, env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            end = time.monotonic() + 60.0
            while started not in log.read_text() and proc.poll() is None:
                assert time.monotonic() < end, log.read_text()
                time.sleep(0.1)
            line = next((x for x in log.read_text().splitlines() if started in x), "")
            assert line and str(dbc) in line, log.read_text()
            proc.send_signal(signal.SIGINT)
            assert proc.wait(30) == 0, log.read_text()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
