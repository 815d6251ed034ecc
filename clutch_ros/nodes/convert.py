"""Conversions between model-core results and rclpy messages (no logic, just fields)."""

from __future__ import annotations

import math

__all__ = ["estimate_to_msg"]


def estimate_to_msg(est, header, msg_type):
    """Build a ``clutch_msgs/ClutchEstimate`` from a model ``Estimate`` and the input header."""
    msg = msg_type()
    msg.header = header
    msg.modelled_torque = float(est.modelled_torque)
    msg.reference_torque = float(est.reference_torque)
    msg.measured_torque = float(est.measured_torque)
    msg.torque_accuracy = float(est.torque_accuracy)
    msg.friction_coefficient = float(est.friction_coefficient)
    msg.lamella_normal_force = [float(v) for v in est.lamella_normal_force]
    msg.spline_friction_force = [float(v) for v in est.spline_friction_force]
    msg.front_pressure = float(est.front_pressure)
    msg.rear_pressure = float(est.rear_pressure)
    msg.pressure_difference = float(est.pressure_difference)
    msg.slip_speed_filtered = float(est.slip_speed_filtered)
    msg.spline_correction = float(est.spline_correction)
    msg.actuating_pressure = float(getattr(est, "actuating_pressure", math.nan))
    msg.lamella_temperature = float(getattr(est, "lamella_temperature", math.nan))
    msg.spline_law = str(est.spline_law)
    msg.overshoot = bool(est.overshoot)
    msg.undershoot = bool(est.undershoot)
    return msg
