"""The chain's skeleton: three bare rclpy processes exchange the chain's messages over DDS."""

import json
import os
import subprocess
import sys
import time

import pytest

from benchmarks import chain_skeleton as skeleton

pytestmark = pytest.mark.ros


def test_the_three_exchange_the_chains_messages(tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    procs = [subprocess.Popen([sys.executable, "-m", "benchmarks.chain_skeleton", role,
                               "--report", str(tmp_path / f"{role}.json"),
                               "--ros-args", "-r", "__ns:=/skeleton"],
                              env=env, stderr=subprocess.PIPE, text=True)
             for role in skeleton.ROLES]
    try:
        time.sleep(8.0)  # start-up, discovery, then a few seconds of traffic
    finally:
        for proc in procs:
            proc.terminate()
        errors = [proc.communicate(timeout=20)[1] for proc in procs]
    assert [proc.returncode for proc in procs] == [0, 0, 0], errors
    rep = {role: json.loads((tmp_path / f"{role}.json").read_text())
           for role in skeleton.ROLES}
    bridge, estimator = (rep["bridge"]["samples"][-1][1],
                         rep["estimator"]["samples"][-1][1])  # (the final counts)
    assert set(bridge) == {"rig_state", "pump_request"}
    controller = rep["controller"]["samples"][-1][1]
    assert set(controller) == {"pressure_command"}
    # the estimator answers the rig_state it received, once each: what the bridge sent, less
    # the ones sent before it had matched (best-effort subscription)
    assert 0 < estimator["clutch_estimate"] <= bridge["rig_state"]
    assert bridge["pump_request"] > 0 and controller["pressure_command"] > 0
    for role, r in rep.items():  # sampled from the start on, counts never decreasing
        times = [t for t, _ in r["samples"]]
        assert len(times) >= 4 and times == sorted(times) and r["ready"] < times[-1], role
        for (_, a), (_, b) in zip(r["samples"], r["samples"][1:], strict=False):
            assert all(b[k] >= a.get(k, 0) for k in b), role


def test_published_between_interpolates_the_samples():
    report = {"ready": 0.0, "samples": [[10.0, {"x": 0}], [11.0, {"x": 100}],
                                        [12.0, {"x": 300}]]}
    # 10.5 s: 50, 11.5 s: 200 (linear between samples); exact in binary floating point
    assert skeleton.published_between(report, 10.5, 11.5) == {"x": 150.0}
    assert skeleton.published_between(report, 10.0, 12.0) == {"x": 300.0}
    assert skeleton.published_between(report, 11.0, 11.0) == {"x": 0.0}
    with pytest.raises(ValueError, match="not 9.0..11.0"):
        skeleton.published_between(report, 9.0, 11.0)  # before its first sample
    with pytest.raises(ValueError):
        skeleton.published_between({"ready": 0.0, "samples": []}, 1.0, 2.0)


def test_help_and_a_bad_rate():
    done = subprocess.run([sys.executable, "-m", "benchmarks.chain_skeleton", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "bridge" in done.stdout
    with pytest.raises(SystemExit) as exc:
        skeleton.main(["bridge", "--rig-rate", "0"])
    assert exc.value.code == 2
