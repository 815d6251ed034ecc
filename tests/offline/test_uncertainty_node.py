"""The estimator process publishes the band ``clutch fit --band`` identified, on its estimate.

A parameter file as ``clutch fit --band adapted_gain`` writes it (the golden-fit parameters,
the error model identified on the adaptive replays of the fitting runs, ``adapt.enabled`` and
``adapt.spline_gain`` true) starts a real ``estimator`` process; an unseen golden run's
RigState samples go to it over DDS. Every published ``modelled_torque_std`` equals the
offline band of the same adapted estimate (:func:`clutch_ros.offline.band.replay_series` +
:func:`clutch_ros.model.uncertainty.torque_std`), so the node adapts the spline gain as the
band was identified with and uses that band (the rate-over-slip term included).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from tests.nodes.rclpy_harness import Harness, connect_estimator, node_process

pytestmark = pytest.mark.ros

DATA = Path(__file__).resolve().parents[1] / "data"
GOLDEN = DATA / "golden" / "bags"
PARAMS = DATA / "uncertainty" / "golden_fit_ff_t.yaml"
FIT = ("table3_seq2_10rpm", "table4_seq1")
RUN = GOLDEN / "table3_seq3_30rpm"  # unseen; a 4 s ramp at 30 rpm: the spline gain adapts


@pytest.fixture(scope="module")
def band_file(tmp_path_factory):
    from clutch_ros.config.params_file import load_params, write_params
    from clutch_ros.offline.band import band_extra, fit_band

    params = load_params(PARAMS)
    model = fit_band([GOLDEN / name for name in FIT], params, "adapted_gain")
    out = tmp_path_factory.mktemp("band") / "fit.yaml"
    write_params(params, out, extra={**model.to_flat(), **band_extra("adapted_gain")})
    return params, model, out


def _messages(bag):
    from clutch_msgs.msg import RigState

    from clutch_ros.bag.rig_states import read_rig_states

    rig = read_rig_states(bag)
    c = rig.columns
    for i in range(len(rig)):
        msg = RigState()
        msg.header.stamp.sec = int(c["header.stamp.sec"][i])
        msg.header.stamp.nanosec = int(c["header.stamp.nanosec"][i])
        msg.actuating_pressure = float(c["actuating_pressure"][i])
        msg.lamella_temperature = float(c["lamella_temperature"][i])
        msg.slip_speed = float(c["slip_speed"][i])
        msg.measured_torque = float(c["measured_torque"][i])
        msg.has_measured_torque = bool(c["has_measured_torque"][i])
        yield msg


def test_the_node_publishes_the_band_of_its_adapted_estimate(band_file, ros_env):
    from clutch_ros.interfaces import stamp_to_ns
    from clutch_ros.model import uncertainty as unc
    from clutch_ros.offline.band import replay_series

    params, model, path = band_file
    assert model.rate_slip > 0.0 and model.recent_weight > 0.0  # both live terms exercised
    assert model.recent_mean_weight > 0.0  # and the recent offset (model/recent_error.py)
    messages = list(_messages(RUN))
    with node_process("estimator", ros_env, "--params-file", str(path),
                      "-p", "estimator.max_sample_age:=0.0") as proc, Harness() as h:
        pub, estimates, _ = connect_estimator(h)
        for k, msg in enumerate(messages):
            pub.publish(msg)
            h.spin_for(0.002)
            if k % 100 == 99:  # never more than ~100 samples in flight (queue 200)
                h.spin_until(lambda k=k: len(estimates) >= k - 20, 20.0, "estimates")
        h.spin_until(lambda: len(estimates) >= len(messages), 30.0, "every estimate")
        assert proc.poll() is None, "estimator died"

    offline = replay_series(RUN, params, "adapted_gain")
    std = unc.torque_std(model, offline["t"], offline["modelled"], offline["slip"],
                         offline["measured"])  # the node feeds the sensor's torque too
    by_ns = {stamp_to_ns(m.header.stamp.sec, m.header.stamp.nanosec): i
             for i, m in enumerate(messages)}
    rows = [by_ns[stamp_to_ns(e.header.stamp.sec, e.header.stamp.nanosec)] for e in estimates]
    assert len(set(rows)) == len(rows) == int(np.isfinite(offline["modelled"]).sum())
    live = np.array([e.modelled_torque_std for e in estimates])
    np.testing.assert_allclose(live, std[rows], rtol=1e-9)
    np.testing.assert_allclose([e.modelled_torque for e in estimates],
                               offline["modelled"][rows], rtol=1e-9)
    # the spline gain adapted (adapt.spline_gain from the file), as the band was fitted
    assert any(not math.isclose(e.spline_gain_scale, 1.0) for e in estimates)
