"""The estimator process with ``estimator.publish_every``: decimated output, model on every sample.

A test node publishes a pressure ramp of RigState samples over DDS to an ``estimator``
process started with ``estimator.publish_every:=3``, one NaN sample among them (skipped,
not counted as accepted). Checked:

- exactly the 1st, 4th, 7th, ... accepted samples come back, in order (``accepted`` and
  ``published`` on /diagnostics say 30 and 10);
- each published estimate equals the model core's ``AdaptiveEstimator`` run over *every*
  sample, not over the published ones only (that would differ: the pack steps over 3 dt);
- ``publish_every`` set live to 1 through the SetParameters service: every following sample
  is published; 0 is refused with a reason and changes nothing.
"""

import math

import numpy as np
import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, connect_estimator, node_process, rig_state

pytestmark = pytest.mark.ros

PRESET = REPO / "params" / "flexiforce_8.yaml"
T0 = 1_700_000_000.0  # [s]
DT = 0.01  # [s]
N_DECIMATED, N_FULL = 30, 6  # samples sent with publish_every 3, then with 1


@pytest.fixture
def estimator(ros_env):
    with node_process("estimator", ros_env, "--params-file", str(PRESET),
                      "-p", "estimator.max_sample_age:=0.0",
                      "-p", "estimator.publish_every:=3") as proc:
        yield proc


def _diag_values(diags) -> dict:
    """Return the key/values of the estimator's newest /diagnostics status."""
    for array in reversed(diags):
        for status in array.status:
            if status.name.endswith("/estimator"):
                return {kv.key: kv.value for kv in status.values}
    return {}


def test_publish_every_decimates_the_output_not_the_model(estimator):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter

    from clutch_ros.config.params_file import load_params
    from clutch_ros.model.adaptation import AdaptiveEstimator
    from clutch_ros.nodes.qos import reliable_qos
    from clutch_ros.nodes.stamps import stamp_to_sec

    msgs = [rig_state(T0 + DT * i, 5e5 + 1e5 * i) for i in range(N_DECIMATED + N_FULL)]
    first, then = msgs[:N_DECIMATED], msgs[N_DECIMATED:]

    def send(h, pub, batch, nan_after=None):
        for k, msg in enumerate(batch):
            pub.publish(msg)
            if k == nan_after:  # a NaN sample: skipped, so not an accepted one
                bad = rig_state(stamp_to_sec(msg.header.stamp) + 0.5 * DT)
                bad.actuating_pressure = math.nan
                pub.publish(bad)
            h.spin_for(0.003)

    def set_every(h, client, value):
        return h.until_answered(lambda: client.set_parameters(
            [Parameter("estimator.publish_every", value=value)]),
            f"set publish_every {value}").results[0]

    with Harness() as h:
        diags = h.collect(DiagnosticArray, "/diagnostics", reliable_qos())
        pub, estimates, client = connect_estimator(h)
        send(h, pub, first, nan_after=10)
        # everything sent was processed once the node reports all of it accepted
        h.spin_until(lambda: _diag_values(diags).get("accepted") == str(N_DECIMATED), 20.0,
                     f"{N_DECIMATED} accepted samples on /diagnostics")
        h.spin_until(lambda: len(estimates) >= N_DECIMATED // 3, 20.0, "the estimates")
        decimated_diag = _diag_values(diags)
        decimated = list(estimates)
        refused = set_every(h, client, 0)
        ok = set_every(h, client, 1)
        send(h, pub, then)
        h.spin_until(lambda: len(estimates) >= len(decimated) + N_FULL, 20.0,
                     "one estimate per sample after the change")
        assert estimator.poll() is None, "estimator died"

    stamps = [stamp_to_sec(e.header.stamp) for e in estimates]
    sent = [stamp_to_sec(m.header.stamp) for m in msgs]
    assert [stamp_to_sec(e.header.stamp) for e in decimated] == sent[:N_DECIMATED:3]
    assert decimated_diag["published"] == str(N_DECIMATED // 3)
    assert decimated_diag["publish_every"] == "3"
    assert decimated_diag["skipped_NonFiniteSample"] == "1"
    assert not refused.successful and refused.reason
    assert ok.successful, ok.reason
    assert stamps == sent[:N_DECIMATED:3] + sent[N_DECIMATED:]

    # the model ran on every sample: the core over all of them, read at the published ones
    core, sparse = AdaptiveEstimator(load_params(PRESET)), AdaptiveEstimator(load_params(PRESET))
    want, skipped = {}, {}
    for i, t in enumerate(sent):
        m = msgs[i]
        args = (t, m.actuating_pressure, m.lamella_temperature, m.slip_speed,
                m.measured_torque)
        want[t] = core.update(*args).estimate
        if i % 3 == 0 and i < N_DECIMATED:  # a model that saw only the published samples
            skipped[t] = sparse.update(*args).estimate
    got = [e.modelled_torque for e in estimates]
    np.testing.assert_allclose(got, [want[t].modelled_torque for t in stamps], rtol=1e-12)
    for e, t in zip(estimates, stamps):
        np.testing.assert_allclose(e.lamella_normal_force, want[t].lamella_normal_force,
                                   rtol=1e-12, atol=1e-9)
    # ... which tells the two apart
    assert max(abs(e.modelled_torque - skipped[t].modelled_torque)
               for e, t in zip(decimated, sent[:N_DECIMATED:3])) > 1.0
