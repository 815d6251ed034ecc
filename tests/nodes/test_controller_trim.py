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
    from clutch_ros.config.params_file import load_params
    from clutch_ros.model.adaptation import scaled_params
    from clutch_ros.model.inverse import pressure_for_torque

    params = scaled_params(load_params(PRESET), SCALE)
    # the rig transmits 10 % less than the model at SCALE
    state = {"request": REQUEST, "measured": 0.9, "std": 0.0}
    with Harness("trim_test") as h:
        commands = _play(h, params, state)
        h.spin_until(lambda: len(commands) > 10 and commands[-1].pressure > 10e5, 60.0,
                     "pressure commands")
        h.spin_for(3.0)  # the trim converges (0.2 s time constant after 0.3 s delay)
        trimmed = commands[-1]
        state["measured"] = math.nan
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


def test_unlearned_scale_is_inverted_at_its_upper_bound(controller):
    """friction_scale_std 0.2 (nothing learned): the step is commanded for a higher μ.

    While a measurement lets the trim act the inverted scale is the larger of s + 0.5 σ
    (``controller.uncertainty_margin``) and the start's (s + 2 σ) / 1.05
    (``controller.uncertainty_range`` 2, defaults): here 1.1 + 0.329. The model at s is right
    here, so the trim then takes the command up to the best estimate's inverse, from below.
    """
    from clutch_ros.config.params_file import load_params
    from clutch_ros.model.adaptation import scaled_params
    from clutch_ros.model.inverse import pressure_for_torque

    base = load_params(PRESET)
    params = scaled_params(base, SCALE)
    # the model at SCALE is right; friction_scale_std 0.2: the adaptation's prior
    state = {"request": 0.0, "measured": 1.0, "std": 0.2}
    with Harness("caution_test") as h:
        commands = _play(h, params, state)
        h.spin_until(lambda: len(commands) > 30, 60.0, "commands at rest (0 N m)")
        state["request"] = REQUEST
        h.spin_until(lambda: commands[-1].requested_torque == REQUEST, 10.0, "the step")
        stepped = len(commands) - 1
        h.spin_for(3.0)  # trim_delay 0.8 s, then the trim converges (0.125 s constant)
        assert controller.poll() is None, "controller died"

    step_t = _stamp(commands[stepped])
    early = [c.pressure for c in commands[stepped:] if _stamp(c) < step_t + 0.4]
    best = pressure_for_torque(params, REQUEST, 40.0, W10)  # the inverse at s = 1.1
    caution = (SCALE + 2 * 0.2) / 1.05 - SCALE  # the start's, above 0.5 σ = 0.1
    cautious = pressure_for_torque(scaled_params(base, SCALE + caution), REQUEST, 40.0, W10)
    print(f"early max {max(early) / 1e5:.2f} bar, cautious {cautious / 1e5:.2f}, "
          f"best {best / 1e5:.2f}, final {commands[-1].pressure / 1e5:.2f}")
    assert cautious < 0.95 * best
    # before the trim acts: never above the cautious inverse's overshoot guard (1.05 x), so
    # below what the best estimate asks for
    assert max(early) <= 1.001 * pressure_for_torque(
        scaled_params(base, SCALE + caution), 1.05 * REQUEST, 40.0, W10) < best
    assert max(early) == pytest.approx(cautious, rel=0.01)  # held there until the trim acts
    final = commands[-1]
    assert final.pressure == pytest.approx(best, rel=0.01)  # the trim undid the caution
    assert final.trim_pressure == pytest.approx(best - cautious, rel=0.05)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _play(h, params, state):
    """Play request, rig state and estimator to the controller every 10 ms; its commands.

    ``state`` (read at each tick): ``request`` [N m]; ``measured``: the measured torque as a
    factor of the model's torque at the last command (NaN: no measurement); ``std``: the
    estimate's friction_scale_std [1]. The estimate's friction scale is SCALE.
    """
    from clutch_msgs.msg import ClutchEstimate, PressureCommand, RigState, TorqueRequest

    from clutch_ros.model.inverse import capacity_scalar
    from clutch_ros.nodes.qos import reliable_qos, sensor_qos

    commands = h.collect(PressureCommand, "pressure_command", reliable_qos())
    req_pub = h.node.create_publisher(TorqueRequest, "torque_request", reliable_qos())
    rig_pub = h.node.create_publisher(RigState, "rig_state", sensor_qos())
    est_pub = h.node.create_publisher(ClutchEstimate, "clutch_estimate", reliable_qos())

    def tick():
        now = h.node.get_clock().now().nanoseconds * 1e-9
        req = TorqueRequest()
        req.torque = state["request"]
        req_pub.publish(req)
        rig_pub.publish(rig_state(now))
        est = ClutchEstimate()
        pressure = commands[-1].pressure if commands else 0.0
        est.modelled_torque = capacity_scalar(params, pressure, 40.0, W10)  # the model
        est.measured_torque = state["measured"] * est.modelled_torque
        est.lamella_temperature, est.slip_speed_filtered = 40.0, W10
        est.friction_scale, est.spline_gain_scale = SCALE, 1.0
        est.friction_scale_std = state["std"]
        est_pub.publish(est)

    h.node.create_timer(0.01, tick)
    return commands


def test_declared_defaults_are_the_control_law_defaults():
    """Each controller.* default is ControllerSettings' own (written once, its own module)."""
    from clutch_ros.model.controller_settings import ControllerSettings
    from clutch_ros.nodes.controller_params import PARAMS, controller_settings

    declared = {spec.name: spec.default for spec in PARAMS}
    assert controller_settings(declared) == ControllerSettings()
