"""closed_loop_summary on a real bag written with rosbags: the figures come from the recording.

A run of the two-step profile below is written with a known measured torque (exactly the
request but for one 0.3 s stretch at 1.2x in a settled hold) and the simulated rig's
/diagnostics reports; the summary must give the fractions, the worst ratio and the real time
the rig dropped during the profile, which is what tells a reader that a run's figures are of a
slowed world.
"""

import math

import numpy as np
import pytest

from clutch_ros.bag.typestore import clutch_typestore, make_msg, rig_state_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.offline.demo_summary import closed_loop_summary
from clutch_ros.rig.request_profile import Segment

T0 = 1_000.0  # [s] profile start (bus clock)
PROFILE = [Segment(3.0, 500.0, 500.0, 1.0), Segment(3.0, 900.0, 900.0, 1.0)]
RATE = 100.0  # [Hz] rig samples


def _diagnostics(stamp: float, lost: float):
    store = clutch_typestore()
    kv = store.types["diagnostic_msgs/msg/KeyValue"]
    status = store.types["diagnostic_msgs/msg/DiagnosticStatus"](
        level=0, name="/rig_sim", message="running", hardware_id="simulated rig",
        values=[kv(key="lost_time_s", value=repr(lost))])
    return make_msg("diagnostic_msgs/msg/DiagnosticArray", int(stamp * 1e9), status=[status])


def _write_run(path, lost_reports):
    t = np.arange(0.0, 6.0, 1.0 / RATE)
    request = np.where(t < 3.0, 500.0, 900.0)
    measured = request.copy()
    high = (t >= 4.5) & (t < 4.8)  # settled (1.5 s into the second hold): 30 samples at 1.2x
    measured[high] *= 1.2
    with BagWriter(path) as writer:
        for topic in ("rig_state", "clutch_estimate", "pressure_command"):  # as recorded
            writer.add_topic(topic)
        if lost_reports is not None:
            writer.add_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        for ti, m in zip(t, measured):
            stamp_ns = int(round((T0 + ti) * 1e9))
            writer.write("rig_state", stamp_ns, rig_state_msg(
                stamp_ns, measured_torque=float(m), has_measured_torque=True,
                actuating_pressure=20e5))
        for stamp, lost in lost_reports or []:
            writer.write("/diagnostics", int(stamp * 1e9), _diagnostics(stamp, lost))
    return t, high


def test_summary_figures_and_the_rig_time_lost_during_the_profile(tmp_path):
    # the rig had dropped 0.2 s before the profile began (start-up), then 0.35 s during it
    reports = [(T0 - 0.5, 0.2), (T0 + 1.0, 0.2), (T0 + 2.0, 0.45), (T0 + 5.0, 0.55)]
    t, high = _write_run(tmp_path / "run", reports)
    s = closed_loop_summary(tmp_path / "run", PROFILE, T0, rated_torque=1000.0)
    settled = ((t >= 1.0) & (t < 3.0)) | (t >= 4.0)  # 1 s after each step
    assert s["settled_samples"] == settled.sum()
    # within_10pct: exact fractions of samples (the 1.2x stretch is the only miss)
    assert s["within_10pct"] == pytest.approx(1.0 - high.sum() / settled.sum(), abs=1e-12)
    assert s["worst_overshoot"] == pytest.approx(1.2, rel=1e-9)
    assert s["worst_overshoot_time_s"] == pytest.approx(4.5, abs=1e-6)  # its first sample
    assert s["longest_overshoot_s"] == pytest.approx(0.29, abs=0.011)  # 30 samples, 10 ms
    assert s["rig_lost_time_s"] == pytest.approx(0.35, abs=1e-12)


def test_no_rig_report_is_nan_and_a_rig_that_kept_time_is_zero(tmp_path):
    for name, reports in (("none", []), ("no_topic", None)):  # a bag without /diagnostics too
        _write_run(tmp_path / name, reports)
        s = closed_loop_summary(tmp_path / name, PROFILE, T0, rated_torque=1000.0)
        assert math.isnan(s["rig_lost_time_s"])
        assert s["within_10pct"] < 1.0  # the rest of the summary is there
    _write_run(tmp_path / "kept", [(T0 + 1.0, 0.0), (T0 + 4.0, 0.0)])
    s = closed_loop_summary(tmp_path / "kept", PROFILE, T0, rated_torque=1000.0)
    assert s["rig_lost_time_s"] == 0.0
