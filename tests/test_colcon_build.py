"""The package builds with colcon on a rig PC layout and every node answers ``--help``.

This is the proof that ``colcon build --paths src/clutch_ros src/clutch_ros/msg_defs`` and
``ros2 run clutch_ros <node>`` work: colcon (colcon-core + colcon-ros from the package index)
builds both packages into a temporary workspace; each executable in
``install/clutch_ros/lib/clutch_ros/`` is then started from a shell that sourced
``install/setup.sh``, exactly as ``ros2 run`` would find and start it.
"""

import os
import shutil
import subprocess
import sys
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
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["AMENT_PREFIX_PATH"] = str(VENV)
    script = f". '{workspace}/install/setup.sh' && cd / && '{exe}' --help"
    done = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, f"{node} --help failed:\n{done.stdout}\n{done.stderr}"
    assert node in done.stdout and "--ros-args" in done.stdout


def test_installed_package_is_the_one_imported(workspace):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["AMENT_PREFIX_PATH"] = str(VENV)
    probe = ("import clutch_ros, clutch_msgs; print(clutch_ros.__file__); "
             "print(clutch_msgs.__file__)")
    script = f". '{workspace}/install/setup.sh' && cd / && '{sys.executable}' -c '{probe}'"
    done = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    ros_file, msgs_file = done.stdout.split()
    assert ros_file.startswith(str(workspace / "install" / "clutch_ros")), ros_file
    assert msgs_file.startswith(str(workspace / "install" / "clutch_msgs")), msgs_file
