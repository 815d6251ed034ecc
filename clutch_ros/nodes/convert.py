"""Conversions to rclpy messages: model estimates, CAN rig samples and raw frames."""

from __future__ import annotations

import math

from clutch_msgs.msg import CanFrame, RigState

from clutch_ros.nodes.stamps import sec_to_stamp
from clutch_ros.rigstate import fill_msg

__all__ = ["adaptation_to_msg", "can_frame_to_ros", "estimate_to_msg", "rig_state_to_ros"]


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




def adaptation_to_msg(msg, status):
    """Fill the adaptation fields of a ``ClutchEstimate`` from an ``AdaptationStatus``."""
    msg.friction_scale = float(status.friction_scale)
    msg.friction_scale_std = float(status.friction_scale_std)
    msg.spline_gain_scale = float(status.spline_gain_scale)
    msg.spline_gain_scale_std = float(status.spline_gain_scale_std)
    msg.adapting = bool(status.adapting)
    msg.adaptation_frozen = status.state == "frozen"
    return msg


def rig_state_to_ros(sample, offset: float = 0.0):
    """Return an rclpy ``RigState`` of ``sample`` stamped ``sample.stamp + offset`` [s].

    The fields come from :func:`clutch_ros.rigstate.fill_msg` (the one RigState mapping).
    """
    return fill_msg(RigState(), sample, sample.stamp + offset)


def can_frame_to_ros(frame, offset: float = 0.0):
    """Return a ``CanFrame`` of a python-can frame (payload cut/padded to 8 bytes)."""
    msg = CanFrame()
    sec_to_stamp(frame.timestamp + offset, msg.header.stamp)
    msg.id, msg.is_rtr = frame.arbitration_id, frame.is_remote_frame
    msg.is_extended, msg.is_error = frame.is_extended_id, frame.is_error_frame
    msg.dlc = min(frame.dlc, 255)
    msg.data = list(bytes(frame.data[:8]).ljust(8, b"\0"))
    return msg
