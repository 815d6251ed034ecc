"""The rig_sim node in lock-step, as a real process: /clock out, the chain's answers in.

This test process plays the chain: on each ``/clock`` it publishes a ``pressure_command`` and a
``clutch_estimate`` stamped with it, sends a PumpRequest frame on the rig's udp_multicast
group and reports that frame on ``pump_request`` with the command's stamp and torques (as
controller, estimator and bridge do). While it answers, the rig's clock advances in
exact 10 ms ticks from a whole-second epoch, with one RigSpeed frame per tick; when it stops
answering, or answers with the command of the previous tick (not the tick's own answer), the
rig waits (its clock stands almost still) and reports the expired waits and what was missing
on /diagnostics; when it answers again, the rig runs on. Nothing here depends on how fast the
machine is: the rig waits for the answers, and the bounds are the rig's own wait timeout.
"""

import os

import pytest

from clutch_ros.canbus import BusConfig, RigDatabase, open_bus
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.cli.processes import NodeProcess, isolated_ros_env, ros_param_args
from tests.canbus.recorder import BusRecorder, bus_params, private_group
from tests.nodes.rclpy_harness import Harness

pytestmark = pytest.mark.ros

DB = RigDatabase()
RIG_SPEED = DB.frame("RigSpeed").frame_id
TICK_NS = 10_000_000
TIMEOUT = 0.3  # [s] the rig's wait bound in this test


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _level(level) -> int:
    """Return a DiagnosticStatus level as an int (rclpy gives constants and fields as bytes)."""
    return level[0] if isinstance(level, bytes) else int(level)


def _timeouts(diags) -> list[tuple[int, int, str]]:
    """(level, lockstep_timeouts, lockstep_last_timeout) of each /rig_sim status received."""
    out = []
    for array in diags:
        for st in array.status:
            if st.name == "/rig_sim":
                kv = {v.key: v.value for v in st.values}
                out.append((_level(st.level), int(float(kv["lockstep_timeouts"])),
                            kv["lockstep_last_timeout"]))
    return out


def _rig_speeds_per_time_frame(frames) -> dict[int, int]:
    """{tick [ns]: RigSpeed frames after its time frame, before the next one}."""
    from clutch_ros.nodes.lockstep import TIME_FRAME_ID

    out: dict[int, int] = {}
    tick = None
    for frame in frames:
        if frame.arbitration_id == TIME_FRAME_ID and not frame.is_extended_id:
            tick = int.from_bytes(frame.data, "little")
            out[tick] = 0
        elif tick is not None and frame.arbitration_id == RIG_SPEED:
            out[tick] += 1
    return out


def test_lockstep_rig_waits_for_the_chain_and_counts_expired_waits(tmp_path):
    from clutch_msgs.msg import ClutchEstimate, PressureCommand
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rosgraph_msgs.msg import Clock

    group, port = private_group()
    codec = PumpRequestCodec(DB)
    sender = open_bus(BusConfig(interface="udp_multicast", channel=group, fd=True,
                                extra={"port": port}))
    with BusRecorder(group, port) as rec:
        rig = NodeProcess("rig_sim", ["--ros-args", *ros_param_args(
            {**bus_params(group, port), "rig.lockstep": True,
             "rig.lockstep_timeout": TIMEOUT})],
            isolated_ros_env(int(os.environ["ROS_DOMAIN_ID"])), tmp_path)
        try:
            with Harness("rig_sim_lockstep_test") as h:
                clocks: list[int] = []
                answering = ["yes"]  # "yes", "no", "previous" (the previous tick's command)
                counter = [0]
                cmd_pub = h.node.create_publisher(PressureCommand, "pressure_command", 10)
                est_pub = h.node.create_publisher(ClutchEstimate, "clutch_estimate", 10)
                applied_pub = h.node.create_publisher(PressureCommand, "pump_request", 10)

                def on_clock(msg) -> None:
                    clocks.append(_ns(msg.clock))
                    if answering[0] == "no":
                        return
                    cmd = PressureCommand()
                    cmd.header.stamp.sec, cmd.header.stamp.nanosec = divmod(
                        _ns(msg.clock) - (TICK_NS if answering[0] == "previous" else 0), 10**9)
                    cmd.requested_torque = float(len(clocks))
                    cmd_pub.publish(cmd)
                    sender.send(codec.encode(0.0, counter[0]))
                    applied_pub.publish(cmd)  # the bridge's report of the command's frame
                    counter[0] = (counter[0] + 1) % 16
                    est = ClutchEstimate()
                    est.header.stamp = msg.clock
                    est_pub.publish(est)

                h.node.create_subscription(Clock, "/clock", on_clock, 10)
                diags = h.collect(DiagnosticArray, "/diagnostics", 50)
                h.spin_until(lambda: len(set(clocks)) >= 300, 120.0, "300 lock-step ticks")
                ticks = sorted(set(clocks))
                assert all(b - a == TICK_NS for a, b in zip(ticks, ticks[1:]))  # none skipped
                assert ticks[0] % TICK_NS == 0 and ticks[0] < 200_000 * 10**9  # the fixed epoch
                # each tick: its time frame, then one RigSpeed (the last tick's may be on the way)
                per_tick = _rig_speeds_per_time_frame(rec.frames)
                assert all(per_tick.get(t) == 1 for t in ticks[:-1]), per_tick

                warn = _level(DiagnosticStatus.WARN)
                for mode, missing in (("no", "clutch_estimate"),
                                      ("previous", "pressure_command stamped at the tick")):
                    answering[0] = mode  # no answer to the tick: the rig waits, bounded
                    before, counted = len(set(clocks)), len(_timeouts(diags))
                    h.spin_for(2.0)
                    # each tick now waits TIMEOUT (for its answer): a few ticks at most
                    assert len(set(clocks)) - before <= 2.0 / TIMEOUT + 2
                    try:
                        h.spin_until(lambda m=missing, c=counted: any(
                            lvl == warn and n > 0 and m in why
                            for lvl, n, why in _timeouts(diags)[c:]), 30.0,
                            f"a WARN with the expired waits naming the missing {missing}")
                    except AssertionError as err:
                        raise AssertionError(f"{err}; got {_timeouts(diags)[-3:]}") from None

                answering[0] = "yes"  # answers again: the rig runs on
                resumed = len(set(clocks))
                h.spin_until(lambda: len(set(clocks)) >= resumed + 200, 120.0,
                             "200 more ticks")
                assert rig.alive()
        finally:
            rig.stop()
            sender.shutdown()
