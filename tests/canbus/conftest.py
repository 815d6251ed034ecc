"""Shared fixtures of the CAN layer tests."""

import uuid

import pytest

from clutch_ros.canbus.dbc import RigDatabase


@pytest.fixture(scope="session")
def db() -> RigDatabase:
    return RigDatabase()


@pytest.fixture
def channel() -> str:
    """Return a virtual-bus channel name no other test uses."""
    return f"test-{uuid.uuid4().hex}"
