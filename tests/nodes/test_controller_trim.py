"""The controller process: adapted model, integral trim and its share in PressureCommand.

A test node plays torque request, rig state and estimator to a real ``controller`` process
over DDS. The estimates say the measured torque is 10 % below the modelled one: the trim
must appear in ``trim_pressure`` and raise the command above the plain (adapted) inverse,
within the pressure limits; when the estimates stop carrying a measurement the trim is
released (``trim_pressure`` 0) after ``controller.trim_hold``.
"""

import math

import pytest

from tests.conftest import REPO
from tests.nodes.rclpy_harness import Harness, node_process, rig_state

pytestmark = pytest.mark.ros

PRESET = REPO / "params" / "flexiforce_8.yaml"
W10 = 10 * 2 * math.pi / 60  # [rad/s]
REQUEST, SCALE = 600.0, 1.1  # [N m], [1]


@pytest.fixture
def controller(ros_env):
    with node_process("controller", ros_env, "--params-file", str(PRESET),
                      "-p", "controller.max_pressure:=30e5") as proc:
        yield proc


def test_trim_share_is_published_and_released_without_measurement(controller):
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest

    from clutch_ros.config.params_file import load_params
    from clutch_ros.model.adaptation import scaled_params
    from clutch_ros.model.inverse import capacity_scalar, pressure_for_torque
    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    params = scaled_params(load_params(PRESET), SCALE)
    state = {"measured": True}
    with Harness("trim_test") as h:
        commands = h.collect(PressureCommand, "pressure_command", reliable_qos())
        req_pub = h.node.create_publisher(TorqueRequest, "torque_request", reliable_qos())
        rig_pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
        est_pub = h.node.create_publisher(ClutchEstimate, "clutch_estimate", reliable_qos())

        def tick():
            now = h.node.get_clock().now().nanoseconds * 1e-9
            req = TorqueRequest()
            req.torque = REQUEST
            req_pub.publish(req)
            rig_pub.publish(rig_state(now))
            est = ClutchEstimate()
            pressure = commands[-1].pressure if commands else 0.0
            est.modelled_torque = capacity_scalar(params, pressure, 40.0, W10)  # the model
            est.measured_torque = (0.9 * est.modelled_torque if state["measured"]
                                   else math.nan)  # the rig transmits 10 % less
            est.lamella_temperature, est.slip_speed_filtered = 40.0, W10
            est.friction_scale, est.spline_gain_scale = SCALE, 1.0
            est_pub.publish(est)

        h.node.create_timer(0.01, tick)
        h.spin_until(lambda: len(commands) > 10 and commands[-1].pressure > 10e5, 60.0,
                     "pressure commands")
        h.spin_for(3.0)  # the trim converges (0.2 s time constant after 0.3 s delay)
        trimmed = commands[-1]
        state["measured"] = False
        h.spin_for(1.0)  # longer than controller.trim_hold (0.25 s)
        released = commands[-1]
        assert controller.poll() is None, "controller died"

    plain = pressure_for_torque(params, REQUEST, 40.0, W10)  # the adapted model's inverse
    # the static loop's fixed point: 0.9 C(p) = request (trim 1/0.9 - 1 = 11 % < 15 % limit)
    needed = pressure_for_torque(params, REQUEST / 0.9, 40.0, W10)
    assert trimmed.trim_pressure > 0.0 and trimmed.pressure <= 30e5
    assert trimmed.pressure == pytest.approx(needed, rel=0.01)
    assert trimmed.trim_pressure == pytest.approx(needed - plain, rel=0.05)
    assert released.trim_pressure == 0.0
    assert released.pressure == pytest.approx(plain, rel=1e-3)
