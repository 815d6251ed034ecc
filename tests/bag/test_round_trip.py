"""Round trip (issue 6): simulated run -> bag (MCAP, sqlite3) -> replay == the live estimator.

1. The simulated rig (truth plant, Table 3 sequence 3 at 10 rpm, 50 Hz) gives a RigState
   run, written once as MCAP and once as sqlite3.
2. Offline: ``clutch replay BAG --params flexiforce_8 --adapt -o OUT`` for each (the live
   estimator adapts its friction scale by default, README "Adaptive estimation", so the
   offline side is the adaptive replay, which runs the same per-sample code).
3. Live: the real ``estimator`` node process (``use_sim_time``, same preset) is fed by the
   ``bag_player`` node process playing the MCAP bag with /clock; the ``recorder`` node
   process records the ClutchEstimate stream the estimator publishes.
4. The recorded live stream equals both replay outputs: same header stamps and frame ids,
   every field within floating-point tolerance (rtol 1e-12, atol 1e-6 in the field's unit;
   the offline batch estimator and the node's per-sample update differ by < 1e-8 at most).
"""

import json
import time
import warnings

import numpy as np
import pytest

from clutch_ros import interfaces
from clutch_ros.bag.arrays import read_columns
from clutch_ros.bag.reader import check_bag
from clutch_ros.cli import main as clutch
from clutch_ros.cli.processes import NodeProcess, ros_param_args
from clutch_ros.offline.rig_runs import simulate_run, write_run
from clutch_ros.rig.scenario import table3_run
from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PRESET = REPO / "params" / "flexiforce_8.yaml"
#: every numeric ClutchEstimate field (spline_correction and spline_gain_scale_std included)
FIELDS = interfaces.estimate_fields(kinds=("float64", "float64[]", "bool"))


def _node(name, params, ros_env, log_dir, extra=()):
    args = ["--ros-args", *extra, *ros_param_args(params)]
    return NodeProcess(name, args, ros_env, log_dir)


def _live_run(bag, out, ros_env, log_dir, n_samples):
    """Play ``bag`` into a live estimator, record its estimates into ``out``."""
    from clutch_msgs.msg import ClutchEstimate
    from diagnostic_msgs.msg import DiagnosticArray

    from clutch_ros.nodes.qos import reliable_qos

    estimator = _node("estimator", {"use_sim_time": True}, ros_env, log_dir,
                      ("--params-file", str(PRESET)))  # fmt: skip
    recorder = _node("recorder", {"recorder.output": str(out),
                                  "recorder.topics": ["clutch_estimate"]}, ros_env, log_dir)
    procs = [estimator, recorder]
    try:  # fmt: skip
        with Harness("round_trip") as h:
            live = h.collect(ClutchEstimate, "clutch_estimate", reliable_qos())
            diags = h.collect(DiagnosticArray, "/diagnostics", 50)
            h.spin_until(lambda: h.node.count_publishers("clutch_estimate") >= 1
                         and h.node.count_subscribers("clutch_estimate") >= 2, 60.0,
                         "the estimator and the recorder")  # fmt: skip
            player = _node("bag_player", {"player.bag": str(bag),
                                          "player.wait_for_subscribers": 1,
                                          "player.start_delay": 0.5}, ros_env, log_dir)
            procs.append(player)  # fmt: skip
            h.spin_until(lambda: not player.alive(), 120.0, "the playback")
            assert player.stop() == 0, player.tail()
            state = {"n": -1, "since": time.monotonic()}

            def settled():  # every estimate in (or, if DDS lost samples, no more coming)
                if len(live) != state["n"]:
                    state["n"], state["since"] = len(live), time.monotonic()
                return len(live) >= n_samples or time.monotonic() - state["since"] > 2.0

            h.spin_until(settled, 60.0, f"{n_samples} live estimates")

            def recorded():
                for array in reversed(diags):
                    for status in array.status:
                        if status.name.endswith("recorder"):
                            return {kv.key: kv.value for kv in status.values}
                return {}

            h.spin_until(lambda: recorded().get("received/clutch_estimate") == str(len(live)),
                         30.0, "the recorder to take every estimate")  # fmt: skip
        for proc in (recorder, estimator):
            assert proc.alive(), proc.tail()
            assert proc.stop(timeout=30.0) == 0, proc.tail()
    finally:
        for proc in procs:
            proc.stop()
    log = recorder.log_path.read_text()
    return json.loads(log.split("recorder summary: ", 1)[1].splitlines()[0])


def test_replay_of_mcap_and_sqlite3_bags_equals_the_live_estimator(ros_env, tmp_path, capsys):
    run = simulate_run(table3_run(3, 10.0), seed=11, rate_hz=50.0, wheel_speeds=False)
    bags = {s: tmp_path / f"rig_{s}" for s in ("mcap", "sqlite3")}
    for storage, bag in bags.items():
        write_run(bag, run, storage=storage)
        assert check_bag(bag) == {"/rig_state": len(run)}

    offline = {}
    for storage, bag in bags.items():
        out = tmp_path / f"replay_{storage}"
        assert clutch(["replay", str(bag), "--params", "flexiforce_8", "--adapt",
                       "-o", str(out)]) == 0
        offline[storage] = read_columns(out, "/clutch_estimate")
    capsys.readouterr()

    # rig_state is best effort (sensor-data QoS, the estimator keeps 5): on an overloaded
    # machine a sample can be lost on its way to the live estimator, whose output then
    # legitimately differs from the bag's replay. Such a run is repeated once.
    for attempt in (1, 2):
        live_bag = tmp_path / f"live{attempt}"
        summary = _live_run(bags["mcap"], live_bag, ros_env, tmp_path / f"logs{attempt}",
                            len(run))  # fmt: skip
        assert summary["/clutch_estimate"]["dropped"] == 0, summary
        live, _, live_strings = read_columns(live_bag, "/clutch_estimate")
        if live["stamp_ns"].tolist() == run.stamp_ns.tolist():
            break
        assert set(live["stamp_ns"].tolist()) < set(run.stamp_ns.tolist()), "foreign stamps"
        warnings.warn(f"live run {attempt}: the estimator got {len(live['stamp_ns'])} of "
                      f"{len(run)} samples (best-effort DDS under load)", stacklevel=1)
    else:
        pytest.fail("the live estimator lost best-effort samples in both runs")
    for storage, (cols, bag_ns, strings) in offline.items():
        assert strings == live_strings == {"header.frame_id": "rig", "spline_law": "ff_t"}
        assert cols["stamp_ns"].tolist() == live["stamp_ns"].tolist() == bag_ns.tolist()
        for field in FIELDS:
            a, b = cols[field].astype(float), live[field].astype(float)
            dev = float(np.nanmax(np.abs(a - b))) if a.size else 0.0
            np.testing.assert_allclose(
                a, b, rtol=1e-12, atol=1e-6, equal_nan=True,
                err_msg=f"{storage} replay vs live, {field}: max |deviation| {dev:g}",
            )  # fmt: skip
