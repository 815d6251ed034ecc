"""The estimator process adapts online, freezes on a dropout with a diagnostic, saves on demand.

A test node publishes RigState samples over DDS to a real ``estimator`` process: the
measured torque comes from the model with μ x 1.2 (a known truth), then the measurement drops
out (``has_measured_torque`` false). Checked:

- every published estimate equals the model core's ``AdaptiveEstimator`` over the same
  samples (torque, friction scale and its std, ``adapting``, ``adaptation_frozen``), and the
  scale reaches 1.2;
- after the dropout the adaptation is frozen, the estimate goes on, and ``/diagnostics``
  reports WARN "adaptation frozen: torque measurement dropped out ...";
- setting ``adapt.save_params_file`` writes a complete parameter file with μ scaled; an
  unwritable path is refused with the reason.
"""

import math

import numpy as np
import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, connect_estimator, node_process

pytestmark = pytest.mark.ros

PRESET = REPO / "params" / "flexiforce_8.yaml"
T0 = 1_700_000_000.0  # [s]
DT = 0.01  # [s]
W10 = 10 * 2 * math.pi / 60  # [rad/s]
N_MEASURED, N_DROPPED = 1200, 150


def _pressure(t):
    """Return the test pressure [Pa] at ``t`` [s]: 2 s holds between 8 and 35 bar."""
    return (10e5, 25e5, 15e5, 35e5, 8e5, 30e5)[int(t // 2.0) % 6]


def _samples():
    """Return (stamp, pressure, temperature, slip, measured torque or NaN) rows."""
    from clutch_ros.config.params_file import load_params
    from clutch_ros.model import ClutchEstimator
    from clutch_ros.model.adaptation import scaled_params

    truth = ClutchEstimator(scaled_params(load_params(PRESET), 1.2))
    rows = []
    for i in range(N_MEASURED + N_DROPPED):
        t = T0 + DT * i
        p, temp = _pressure(DT * i), 40.0 + 0.5 * DT * i
        torque = truth.update(t, p, temp, W10).modelled_torque
        rows.append((t, p, temp, W10, torque if i < N_MEASURED else math.nan))
    return rows


def _msg(row):
    from clutch_msgs.msg import RigState

    from clutch_ros.nodes.stamps import sec_to_stamp

    msg = RigState()
    sec_to_stamp(row[0], msg.header.stamp)
    msg.actuating_pressure, msg.lamella_temperature, msg.slip_speed = row[1], row[2], row[3]
    msg.has_measured_torque = not math.isnan(row[4])
    msg.measured_torque = row[4] if msg.has_measured_torque else 0.0
    return msg


@pytest.fixture
def estimator(ros_env):
    with node_process("estimator", ros_env, "--params-file", str(PRESET),
                      "-p", "estimator.max_sample_age:=0.0") as proc:
        yield proc


def test_adapts_freezes_with_a_diagnostic_and_saves(estimator, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter import Parameter

    from clutch_ros.config.params_file import load_params
    from clutch_ros.model.adaptation import AdaptiveEstimator
    from clutch_ros.nodes.qos import reliable_qos
    from clutch_ros.nodes.stamps import stamp_to_sec

    rows = _samples()
    with Harness() as h:
        diags = h.collect(DiagnosticArray, "/diagnostics", reliable_qos())
        pub, estimates, client = connect_estimator(h)
        for k, row in enumerate(rows):
            pub.publish(_msg(row))
            h.spin_for(0.002)
            if k % 100 == 99:  # never more than ~100 samples in flight (queue 200)
                h.spin_until(lambda k=k: len(estimates) >= k - 20, 20.0, "estimates")
        h.spin_until(lambda: len(estimates) >= len(rows), 30.0, f"{len(rows)} estimates")

        def frozen_warned():
            return any(s.name.endswith("/estimator") and s.level == DiagnosticStatus.WARN
                       and "adaptation frozen: torque measurement dropped out" in s.message
                       for d in diags for s in d.status)
        h.spin_until(frozen_warned, 10.0, "the frozen-adaptation diagnostic")

        target = tmp_path / "adapted.yaml"
        ok = h.until_answered(lambda: client.set_parameters(
            [Parameter("adapt.save_params_file", value=str(target))]), "the save").results[0]
        refused = h.until_answered(lambda: client.set_parameters(
            [Parameter("adapt.save_params_file", value="/proc/no/such/dir/x.yaml")]),
            "the refused save").results[0]
        assert estimator.poll() is None, "estimator died"

    got = {round(stamp_to_sec(e.header.stamp), 6): e for e in estimates}
    assert len(got) == len(rows)
    core = AdaptiveEstimator(load_params(PRESET))
    out = [got[round(row[0], 6)] for row in rows]
    # the core on the stamps the node saw (nanosecond stamps, converted as the node does)
    want = [core.update(stamp_to_sec(e.header.stamp), *row[1:]) for e, row in zip(out, rows)]
    # same code on the same float64 stamps and values: equal to the last bit (allow 1e-12)
    np.testing.assert_allclose([e.modelled_torque for e in out],
                               [w.estimate.modelled_torque for w in want], rtol=1e-12)
    np.testing.assert_allclose([e.friction_scale for e in out],
                               [w.adaptation.friction_scale for w in want], rtol=1e-12)
    np.testing.assert_allclose([e.friction_scale_std for e in out],
                               [w.adaptation.friction_scale_std for w in want], rtol=1e-12)
    assert [e.adapting for e in out] == [w.adaptation.adapting for w in want]
    assert [e.adaptation_frozen for e in out] == [w.adaptation.state == "frozen" for w in want]
    # the truth is mu x 1.2: learned before the dropout, kept after it
    measured, dropped = out[:N_MEASURED], out[N_MEASURED:]
    assert sum(e.adapting for e in measured) > 0.3 * N_MEASURED
    assert abs(measured[-1].friction_scale - 1.2) < 0.01
    assert not any(e.adapting for e in dropped) and dropped[-1].adaptation_frozen
    assert len({e.friction_scale for e in dropped[50:]}) == 1
    assert all(math.isfinite(e.modelled_torque) and math.isnan(e.measured_torque)
               for e in dropped)
    # the save: a complete parameter file with mu scaled; a bad path refused with a reason
    assert ok.successful, ok.reason
    saved = load_params(target)
    assert saved.friction.mu_ref / load_params(PRESET).friction.mu_ref == \
        pytest.approx(core.friction_scale, rel=1e-9)
    assert not refused.successful and "x.yaml" in refused.reason
