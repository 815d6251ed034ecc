"""The bag_player node as a real process: /clock for use_sim_time nodes, rate, topics, errors.

The bag: 3 s of a simulated rig run at 100 Hz (RigState) plus a 10 Hz TorqueRequest, stamped
in 2001 (far from the wall clock), so a node that runs on the bag's clock is told apart from
one on wall time:

- an estimator started with ``use_sim_time:=true`` gets the samples with their recorded
  stamps and answers with those stamps; its clock follows /clock (its /diagnostics stamps lie
  in the bag's time range, and no sample is skipped as stale, which on wall time every sample
  would be, 25 years old);
- ``player.rate`` scales the playback time, ``player.topics`` selects topics, ``player.loop``
  repeats;
- a truncated bag and a bag with a corrupt message give one clear error line and a non-zero
  exit code; nothing corrupt is published.
"""

import json
import struct
import time

import numpy as np
import pytest

from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.typestore import TORQUE_REQUEST_TYPE
from clutch_ros.bag.writer import BagWriter
from clutch_ros.cli.processes import NodeProcess, ros_param_args
from clutch_ros.offline.rig_runs import simulate_run, write_run
from clutch_ros.rig.scenario import table3_run
from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness

pytestmark = [pytest.mark.ros, pytest.mark.slow]

START_NS = 1_000_000_000 * 1_000_000_000  # 2001-09-09
PRESET = REPO / "params" / "flexiforce_8.yaml"


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """RigState at 100 Hz for 3 s and TorqueRequest at 10 Hz; returns (path, run)."""
    run = simulate_run(table3_run(3, 10.0), seed=3, rate_hz=100.0, duration=3.0,
                       start_ns=START_NS, wheel_speeds=False)  # fmt: skip
    path = tmp_path_factory.mktemp("player") / "run"
    with BagWriter(path) as writer:
        topic = writer.add_topic("/rig_state")
        write_columns(writer, topic, TemplateSerializer("clutch_msgs/msg/RigState",
                      frame_id="rig", ff_voltages=np.zeros(8)), run.stamp_ns,
                      {k: v for k, v in run.columns.items() if k != "wheel_speeds"})  # fmt: skip
        req = writer.add_topic("/torque_request")
        stamps = run.stamp_ns[::10]
        write_columns(writer, req, TemplateSerializer(TORQUE_REQUEST_TYPE), stamps,
                      {"torque": np.arange(len(stamps), dtype=float)})  # fmt: skip
    return path, run


def player(ros_env, log_dir, params, name="bag_player"):
    args = ["--ros-args", "-r", f"__node:={name}", *ros_param_args(params)]
    proc = NodeProcess("bag_player", args, ros_env, log_dir / name)
    proc.name = name
    return proc


def wait_exit(h, proc, timeout):
    h.spin_until(lambda: not proc.alive(), timeout, f"{proc.name} to finish")
    return proc.stop()


def settle_estimates(h, estimates, quiet: float = 1.5, timeout: float = 30.0) -> None:
    """Spin until no estimate arrived for ``quiet`` seconds (best effort: some may be lost)."""
    state = {"n": -1, "since": time.monotonic()}

    def quiet_now():
        if len(estimates) != state["n"]:
            state["n"], state["since"] = len(estimates), time.monotonic()
        return time.monotonic() - state["since"] > quiet

    h.spin_until(quiet_now, timeout, "the estimates to stop")


def summary_of(proc) -> dict:
    log = proc.log_path.read_text()
    assert "Traceback" not in log, log
    return json.loads(log.split("player summary: ", 1)[1].splitlines()[0])


def test_use_sim_time_estimator_follows_the_bag_clock(bag, ros_env, tmp_path):
    from clutch_msgs.msg import ClutchEstimate, RigState
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    path, run = bag
    args = ["--ros-args", "--params-file", str(PRESET), "-p", "use_sim_time:=true"]
    estimator = NodeProcess("estimator", args, ros_env, tmp_path)
    play = None
    try:
        with Harness() as h:
            estimates = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
            played = h.collect(RigState, "rig_state", sensor_qos())
            diags = h.collect(DiagnosticArray, "/diagnostics", 50)
            clock = h.collect(Clock, "/clock", 100)
            h.spin_until(lambda: h.node.count_publishers("clutch_estimate") > 0, 60.0,
                         "the estimator to start")  # fmt: skip
            play = player(ros_env, tmp_path, {
                "player.bag": str(path), "player.topics": ["rig_state"],
                "player.wait_for_subscribers": 2, "player.start_delay": 0.3})  # fmt: skip
            assert wait_exit(h, play, 90.0) == 0, play.tail()
            settle_estimates(h, estimates)
            assert estimator.alive(), estimator.tail()
    finally:
        estimator.stop()
        if play is not None:
            play.stop()

    summary = summary_of(play)
    assert summary["published"] == len(run) == 300 and summary["error"] is None
    assert summary["topics"] == ["/rig_state"]
    recorded = run.stamp_ns.tolist()
    got = [e.header.stamp.sec * 1_000_000_000 + e.header.stamp.nanosec for e in estimates]
    seen = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in played]
    assert set(seen) <= set(recorded) and len(seen) >= 0.9 * len(recorded)  # best effort
    assert set(got) <= set(recorded) and len(got) >= 0.9 * len(recorded), len(got)
    assert got == sorted(got) and all(e.header.frame_id == "rig" for e in estimates)
    # the node's clock is the bag's: diagnostics stamped in 2001, no sample "stale"
    first_s, last_s = recorded[0] / 1e9, recorded[-1] / 1e9
    stamps = [d.header.stamp.sec + d.header.stamp.nanosec * 1e-9 for d in diags
              if any(s.name.endswith("estimator") for s in d.status)]  # fmt: skip
    in_bag = [s for s in stamps if first_s - 0.5 <= s <= last_s + 0.5]
    print(f"{len(got)} estimates of {len(recorded)} samples; diagnostics at {stamps}")
    assert in_bag, f"no estimator diagnostics on the bag's clock: {stamps[:5]}"
    assert all(s < first_s + 10 or s > 1.5e9 for s in stamps)  # bag time, or wall time after
    values = {kv.key: kv.value for d in diags for s in d.status if s.name.endswith("estimator")
              for kv in s.values}  # fmt: skip
    assert int(values.get("skipped_stale", 0)) <= 0.1 * len(recorded), values  # wall: all
    clock_s = [c.clock.sec + c.clock.nanosec * 1e-9 for c in clock]
    assert clock_s and all(first_s - 1e-6 <= c <= last_s + 1e-6 for c in clock_s)
    assert clock_s == sorted(clock_s)


def test_rate_and_topic_selection(bag, ros_env, tmp_path):
    from clutch_msgs.msg import RigState, TorqueRequest
    from rosgraph_msgs.msg import Clock

    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    path, run = bag
    with Harness() as h:
        requests = h.collect(TorqueRequest, "torque_request", reliable_qos())
        rig = h.collect(RigState, "rig_state", sensor_qos())
        clock = h.collect(Clock, "/clock", 100)
        play = player(ros_env, tmp_path, {
            "player.bag": str(path), "player.topics": ["/torque_request"], "player.rate": 4.0,
            "player.wait_for_subscribers": 1, "player.start_delay": 0.2})  # fmt: skip
        try:
            assert wait_exit(h, play, 90.0) == 0, play.tail()
            h.spin_until(lambda: len(requests) >= 30, 10.0, "every torque request")
            h.spin_for(0.3)
        finally:
            play.stop()
    summary = summary_of(play)
    assert summary["published"] == 30 and summary["topics"] == ["/torque_request"]
    assert [r.torque for r in requests] == [float(i) for i in range(30)]  # reliable: all
    assert [r.header.stamp.sec * 10**9 + r.header.stamp.nanosec for r in requests] == \
        run.stamp_ns[::10].tolist()  # fmt: skip
    assert rig == []  # not selected
    # 2.7 s of bag time at 4x: never faster than 1/4 of it, well below real time
    span = (run.stamp_ns[::10][-1] - run.stamp_ns[0]) / 1e9
    assert summary["wall_s"] >= span / 4.0 - 1e-3
    assert summary["wall_s"] < span, summary
    assert clock and clock[-1].clock.sec * 10**9 + clock[-1].clock.nanosec >= run.stamp_ns[-10]


def test_loop_repeats_the_bag_until_stopped(bag, ros_env, tmp_path):
    from clutch_msgs.msg import TorqueRequest

    from clutch_ros.nodes.qos import reliable_qos

    path, _ = bag
    with Harness() as h:
        requests = h.collect(TorqueRequest, "torque_request", reliable_qos())
        play = player(ros_env, tmp_path, {
            "player.bag": str(path), "player.topics": ["torque_request"], "player.rate": 20.0,
            "player.loop": True, "player.wait_for_subscribers": 1, "player.start_delay": 0.0,
            "player.publish_clock": False})
        try:  # fmt: skip
            h.spin_until(lambda: len(requests) >= 75, 60.0, "the bag to repeat")
            assert play.alive()
        finally:
            code = play.stop()
    assert code == 0
    torques = [r.torque for r in requests]
    assert torques[:75] == [float(i % 30) for i in range(75)]


def test_unknown_topic_truncated_and_corrupt_bags(bag, ros_env, tmp_path):
    path, run = bag
    # a topic the bag lacks
    proc = player(ros_env, tmp_path, {"player.bag": str(path), "player.topics": ["nope"]},
                  "p_topic")  # fmt: skip
    deadline = time.monotonic() + 60.0
    truncated = tmp_path / "truncated"
    truncated.mkdir()
    (truncated / "metadata.yaml").write_bytes((path / "metadata.yaml").read_bytes())
    data = (path / "run.mcap").read_bytes()
    (truncated / "run.mcap").write_bytes(data[: len(data) // 2])
    corrupt = tmp_path / "corrupt"
    run = simulate_run(table3_run(3, 10.0), seed=1, rate_hz=100.0, duration=1.0,
                       start_ns=START_NS, wheel_speeds=False)  # fmt: skip
    write_run(corrupt, run)
    mcap = corrupt / "corrupt.mcap"
    raw = bytearray(mcap.read_bytes())
    at = raw.find(struct.pack("<QQ", int(run.stamp_ns[50]), int(run.stamp_ns[50]))) + 16
    raw[at + 12 : at + 16] = struct.pack("<I", 0x7FFFFFFF)  # header.frame_id length of msg 51
    # the same damage in a chunk whose checksum still guards it (our writer's bags)
    checked = tmp_path / "checked"
    checked.mkdir()
    (checked / "metadata.yaml").write_bytes((corrupt / "metadata.yaml").read_bytes())
    (checked / "corrupt.mcap").write_bytes(bytes(raw))
    # ... and in a chunk without one (CRC 0: a writer that computes none, rosbags' own)
    _zero_chunk_crc(raw, at)
    mcap.write_bytes(bytes(raw))
    procs = [proc,
             player(ros_env, tmp_path, {"player.bag": str(truncated)}, "p_truncated"),
             player(ros_env, tmp_path, {"player.bag": str(corrupt), "player.start_delay": 0.0},
                    "p_corrupt"),
             player(ros_env, tmp_path, {"player.bag": str(checked), "player.start_delay": 0.0},
                    "p_checked")]  # fmt: skip
    while any(p.alive() for p in procs) and time.monotonic() < deadline:
        time.sleep(0.1)
    codes = [p.stop() for p in procs]
    logs = [p.log_path.read_text() for p in procs]
    assert all("Traceback" not in log for log in logs), logs
    assert codes[0] == 2 and "player.topics: nope not in" in logs[0], logs[0]
    assert codes[1] == 2 and "bag_player: error:" in logs[1] and "run.mcap" in logs[1], logs[1]
    assert codes[2] == 1, logs[2]
    (line,) = [x for x in logs[2].splitlines() if "playback stopped:" in x]
    assert "corrupt.mcap: message 51 on /rig_state" in line and "cannot be decoded" in line
    assert summary_of(procs[2])["published"] == 50
    # a checksum mismatch: the chunk is refused whole (nothing unverified is published), with
    # the way to the messages before the damage
    assert codes[3] == 1, logs[3]
    (line,) = [x for x in logs[3].splitlines() if "playback stopped:" in x]
    assert "corrupt.mcap: cannot read messages: Chunk checksum mismatch" in line, line
    assert "clutch replay --recover" in line
    assert summary_of(procs[3])["published"] == 0


def _zero_chunk_crc(raw: bytearray, offset: int) -> None:
    """Set the uncompressed CRC of the MCAP chunk holding byte ``offset`` to 0 (unchecked).

    Records after the 8-byte magic: opcode u8, length u64, body; a Chunk (0x06) body starts
    with message start and end time and uncompressed size (u64 each), then the CRC (u32).
    """
    pos = 8
    while pos < len(raw):
        opcode, length = raw[pos], struct.unpack_from("<Q", raw, pos + 1)[0]
        body = pos + 9
        if opcode == 0x06 and body <= offset < body + length:
            raw[body + 24 : body + 28] = b"\0\0\0\0"
            return
        pos = body + length
    raise AssertionError(f"no chunk holds byte {offset}")
