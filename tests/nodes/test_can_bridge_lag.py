"""The can_bridge node running late: coherent bus data is not flagged stale, the lag is reported.

``stale_mask`` ages each signal group at the sample's own stamp (the newest frame's bus time,
see ``clutch_ros.nodes.can_bridge``). A bridge that falls behind the bus (here: stopped with
SIGSTOP for 50 ms, until three stops held trigger frames of the simulated rig, which keeps
sending 1 kHz frames) publishes
its backlog late, and those samples must carry the bus as it was at their stamp, without
stale flags; how late it ran shows on /diagnostics as ``receive_lag_max_s``.

The oracle is the bus itself (a python-can receiver in this process, kernel receive times as
in ``tests/nodes/test_can_bridge.py``): for every RigState, the expected ``stale_mask`` is
computed from the frames up to its stamp with the assembler's group ages, so a real gap of
the rig (it is a Python process on a loaded machine too) is expected to be flagged, and the
bridge's own lateness is not.
"""

import os
import signal
import time

import pytest

from clutch_ros.canbus import RigDatabase, RigStateAssembler
from clutch_ros.cli.processes import NodeProcess, isolated_ros_env, ros_param_args
from clutch_ros.nodes.can_bridge_params import PARAMS
from clutch_ros.nodes.stamps import stamp_to_sec
from tests.canbus.recorder import (
    BusRecorder,
    bus_params,
    expected_stale_mask,
    frame_times,
    private_group,
)
from tests.nodes.rclpy_harness import Harness

pytestmark = pytest.mark.ros

DB = RigDatabase()
GROUPS = RigStateAssembler(DB).groups
STOP = 0.05  # [s] each SIGSTOP: ~120 rig frames queue in the bridge's socket, none is lost
AFTER = 300  # samples collected after the stops, whatever the machine's load
MAX_STOPS = 30  # stops tried until three held trigger frames
CLOCK_SKEW = 0.002  # [s] kernel receive stamps vs this process's time.time() (same clock)
RATE = next(p.default for p in PARAMS if p.name == "bridge.rate")  # [Hz] the bridge's default


def triggers(rec) -> list[float]:
    """Bus times [s] of the rig's trigger frames (RigSpeed) the recorder has seen so far."""
    return frame_times(list(rec.frames), DB).get("RigSpeed", [])


def stopped_now(pid: int, timeout: float = 5.0) -> float:
    """Wait until every thread of ``pid`` is stopped; return the time [s] it was seen so.

    ``os.kill(pid, SIGSTOP)`` returns before the process stops: on a loaded machine its
    threads may run (and publish) for milliseconds after, so a stop window must start when
    /proc shows all of them stopped, not at the call (issue 23).
    """
    deadline = time.monotonic() + timeout
    while True:
        states = []
        for tid in os.listdir(f"/proc/{pid}/task"):
            try:
                with open(f"/proc/{pid}/task/{tid}/stat") as f:
                    states.append(f.read().rsplit(")", 1)[1].split()[0])
            except FileNotFoundError:  # a thread that ended
                continue
        if states and all(s in "tT" for s in states):
            return time.time()
        assert time.monotonic() < deadline, f"process {pid} did not stop: {states}"
        time.sleep(0.0005)


def publishable_early(seen: list[float], a: float, b: float) -> bool:
    """Return whether the bridge must publish a sample stamped in the first half of [a, b).

    The pacer publishes a trigger frame once a token has accrued, one per ``1 / bridge.rate``
    of bus time: of two trigger frames at least that far apart, one is published. One early
    trigger alone is not enough: a rig starved by a loaded machine may send a single one
    right after a publication and the rest late (seen in a fresh-clone CI beside two hogs).
    """
    early = [t for t in seen if a <= t < b - STOP / 2]
    return bool(early) and early[-1] - early[0] >= 1.0 / RATE


def stamp_span(got) -> float:
    """Return the time [s] the received RigState stamps span."""
    return (stamp_to_sec(got[-1][1].header.stamp) - stamp_to_sec(got[0][1].header.stamp)
            if got else 0.0)


def test_a_late_bridge_flags_only_what_the_bus_lacks_and_reports_its_lag(tmp_path):
    from clutch_msgs.msg import RigState
    from diagnostic_msgs.msg import DiagnosticArray

    from clutch_ros.nodes.qos import reliable_qos

    group, port = private_group()
    env = isolated_ros_env(int(os.environ["ROS_DOMAIN_ID"]))
    got = []  # (receive wall time [s], RigState)
    stops = []  # (wall time [s] all its threads were seen stopped, just before SIGCONT)
    with BusRecorder(group, port) as rec:
        procs = [NodeProcess(name, ["--ros-args", *ros_param_args(params)], env, tmp_path)
                 for name, params in (("rig_sim", {**bus_params(group, port),
                                                   "rig.slip_speed": 1.047}),
                                      ("can_bridge", bus_params(group, port)))]
        try:
            with Harness("can_bridge_lag_test") as h:
                # reliable and deep: the backlog a resumed bridge publishes in a burst must all
                # reach the oracle (a best-effort reader of depth 5 in a process starved by a
                # loaded machine dropped its oldest samples, the very ones stamped in a stop)
                h.node.create_subscription(RigState, "rig_state",
                                           lambda m: got.append((time.time(), m)),
                                           reliable_qos(1000))
                diags = h.collect(DiagnosticArray, "/diagnostics", 50)
                # waits are for data, not for time: a loaded machine publishes fewer samples
                h.spin_until(lambda: stamp_span(got) > 1.0, 90.0, "1 s of rig_state")
                # stop the bridge until three stops held publishable trigger frames of the
                # rig in their first half (a starved rig may send none there): bounded
                for _ in range(MAX_STOPS):
                    os.kill(procs[1].pid, signal.SIGSTOP)
                    stopped = stopped_now(procs[1].pid)
                    time.sleep(STOP)
                    resumed = time.time()
                    os.kill(procs[1].pid, signal.SIGCONT)
                    stops.append((stopped, resumed))
                    h.spin_for(0.4)
                    seen = triggers(rec)
                    if sum(publishable_early(seen, a, b) for a, b in stops) >= 3:
                        break
                n = len(got)
                h.spin_until(lambda: len(got) > n + AFTER, 60.0, f"{AFTER} more rig_state")
                h.spin_for(1.2)  # one more /diagnostics report
                assert all(p.alive() for p in procs)
        finally:
            for p in procs:
                p.stop()

        lost = rec.drops()  # before the recorder closes its socket
    # the oracle is this process's recording: frames it lost (this process starved on a
    # loaded machine) would make it expect stale groups the bridge really had
    assert not lost, f"the test's bus recorder lost {lost} frames: the oracle is incomplete"
    times = frame_times(rec.frames, DB)
    start = min(ts[0] for ts in times.values()) + 0.6  # every 100 ms frame seen once
    checked = [(rt, m) for rt, m in got if stamp_to_sec(m.header.stamp) > start]
    assert len(checked) > AFTER  # the waits above guarantee this much unless samples vanished
    # the bridge did run late: a sample stamped while it was stopped cannot have left before
    # it was resumed, so it went out at least (resume - stamp) late. The oracle is these
    # windows, not a fixed lateness: a starved rig may have sent little during a stop.
    held = [(rt, stamp_to_sec(m.header.stamp), b) for rt, m in got for a, b in stops
            if a <= stamp_to_sec(m.header.stamp) < b]
    assert held, f"no rig_state stamped within the bridge's stops {stops}"
    assert all(rt >= b - CLOCK_SKEW for rt, _, b in held), \
        [(round(rt - b, 4), round(b - st, 4)) for rt, st, b in held if rt < b - CLOCK_SKEW]
    late = max(b - st for _, st, b in held)  # [s] the least lag the bridge must have seen
    assert late > STOP / 2, (late, stops)  # (a stop held a trigger frame this long: the loop)
    mismatches = []
    for rt, msg in checked:
        stamp = stamp_to_sec(msg.header.stamp)
        expected = expected_stale_mask(stamp, times, GROUPS)
        if expected is not None and msg.stale_mask != expected:
            mismatches.append((round(stamp - start, 3), round(rt - stamp, 3), msg.stale_mask,
                               expected))
    assert not mismatches, mismatches[:20]
    lags = [float(kv.value) for a in diags for s in a.status if s.name == "/can_bridge"
            for kv in s.values if kv.key == "receive_lag_max_s"]
    # the bridge measured at least the lag the stops forced on it (it reads a frame after
    # SIGCONT, its stamp before SIGSTOP ended)
    assert lags and max(lags) >= late - CLOCK_SKEW, (lags, late)
