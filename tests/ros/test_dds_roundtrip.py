"""Two separate OS processes exchange every clutch_msgs type over DDS, every field intact."""

import json
import subprocess

import pytest

from tests.conftest import PYTHON, REPO
from tests.ros.reference_messages import TYPES, make_reference, to_plain

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("type_name", sorted(TYPES))
def test_message_crosses_process_boundary_intact(type_name, ros_env):
    peer = ["-m", "tests.ros.pubsub_peer"]
    sub = subprocess.Popen([PYTHON, *peer, "sub", type_name, "30"], cwd=REPO, env=ros_env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pub = subprocess.Popen([PYTHON, *peer, "pub", type_name, "30"], cwd=REPO, env=ros_env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        out, err = sub.communicate(timeout=60)
    finally:
        pub.kill()
        pub.wait()
    assert sub.returncode == 0, f"subscriber received nothing: {err[-2000:]}"
    received = json.loads(out.strip().splitlines()[-1])
    expected = to_plain(make_reference(type_name))
    assert received == expected
    # The reference message really is non-default in every field (else the check is weak).
    default = to_plain(TYPES[type_name]())
    same = [name for name in expected if name != "header" and expected[name] == default[name]]
    assert not same, f"reference leaves fields at their defaults: {same}"
