"""Shared test fixtures: an isolated ROS 2 environment per test session.

Every test that starts rclpy processes gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (multicast
discovery does not work on every machine) and a ROS_DOMAIN_ID unique to this pytest run, so
two test runs (or a test run and a demo) on one machine never see each other's topics.
"""

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PYTHON = sys.executable

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")


def _child_env() -> dict:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture
def ros_env():
    """Environment for child processes that take part in this run's ROS graph."""
    return _child_env()


@pytest.fixture(scope="module")
def ros_env_module():
    """Module-scoped :func:`ros_env` for expensive module fixtures."""
    return _child_env()
