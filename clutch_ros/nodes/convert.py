"""Conversions to rclpy messages: model estimates, CAN rig samples and raw frames."""

from __future__ import annotations

from array import array

import numpy as np
from clutch_msgs.msg import CanFrame, RigState

from clutch_ros.nodes.stamps import sec_to_stamp
from clutch_ros.rigstate import fill_msg

__all__ = ["EstimateMessage", "can_frame_to_ros", "rig_state_to_ros"]


class EstimateMessage:
    """One preallocated ``clutch_msgs/ClutchEstimate``, refilled for every published estimate.

    Building a ClutchEstimate per sample cost more than publishing it (the constructor
    alone about 40 µs, the per-lamella lists another 13 µs); this keeps one message and
    copies the model's per-lamella arrays [N] into numpy views of the message's own
    ``array('d')`` buffers. Safe because rclpy's ``publish`` serialises the message before
    it returns: refill it only after the previous ``publish`` call returned (one thread).
    """

    def __init__(self, msg_type):
        """Preallocate one ``msg_type`` (``ClutchEstimate``) message."""
        self.msg = msg_type()
        self._normal = self._spline = None  # numpy views on the message arrays [N]

    def _resize(self, n: int) -> None:
        """Give the message float64 arrays of ``n`` lamellas (at start, or a new count)."""
        msg = self.msg
        msg.lamella_normal_force = array("d", bytes(8 * n))
        msg.spline_friction_force = array("d", bytes(8 * n))
        self._normal = np.frombuffer(msg.lamella_normal_force, dtype=np.float64)
        self._spline = np.frombuffer(msg.spline_friction_force, dtype=np.float64)

    def fill(self, est, status, header):
        """Fill the message from a model ``Estimate`` and ``AdaptationStatus``; return it.

        ``header`` (the input RigState's) is referenced, not copied: the estimate carries the
        stamp of the sample it was computed from.
        """
        msg = self.msg
        normal, spline = est.lamella_normal_force, est.spline_friction_force
        if self._normal is None or len(normal) != len(self._normal):
            self._resize(len(normal))
        self._normal[:] = normal
        self._spline[:] = spline
        msg.header = header
        msg.modelled_torque = float(est.modelled_torque)
        msg.reference_torque = float(est.reference_torque)
        msg.measured_torque = float(est.measured_torque)
        msg.torque_accuracy = float(est.torque_accuracy)
        msg.friction_coefficient = float(est.friction_coefficient)
        msg.front_pressure = float(est.front_pressure)
        msg.rear_pressure = float(est.rear_pressure)
        msg.pressure_difference = float(est.pressure_difference)
        msg.slip_speed_filtered = float(est.slip_speed_filtered)
        msg.spline_correction = float(est.spline_correction)
        msg.actuating_pressure = float(est.actuating_pressure)
        msg.lamella_temperature = float(est.lamella_temperature)
        msg.spline_law = est.spline_law
        msg.overshoot = bool(est.overshoot)
        msg.undershoot = bool(est.undershoot)
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
