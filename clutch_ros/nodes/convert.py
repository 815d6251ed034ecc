"""Conversions to rclpy messages: model estimates, CAN rig samples and raw frames."""

from __future__ import annotations

from array import array

import numpy as np
from clutch_msgs.msg import CanFrame, RigState

from clutch_ros.interfaces import ESTIMATE_FIELDS
from clutch_ros.nodes.stamps import sec_to_stamp
from clutch_ros.rigstate import fill_msg

__all__ = ["EstimateMessage", "can_frame_to_ros", "rig_state_to_ros"]


#: (message field, source attribute) per kind, from the one ClutchEstimate field table
_FIELDS = {kind: tuple((f.name, f.attr) for f in ESTIMATE_FIELDS
                       if f.source == "estimate" and f.kind == kind)
           for kind in ("float64", "float64[]", "bool", "string")}
_ADAPTATION = tuple((f.name, f.kind, f.attr, f.state) for f in ESTIMATE_FIELDS
                    if f.source == "adaptation")


class EstimateMessage:
    """One preallocated ``clutch_msgs/ClutchEstimate``, refilled for every published estimate.

    The fields and where each comes from are :data:`clutch_ros.interfaces.ESTIMATE_FIELDS`
    (the table ``clutch replay -o`` writes from too). Building a ClutchEstimate per sample
    cost more than publishing it (the constructor alone about 40 µs, the per-lamella lists
    another 13 µs); this keeps one message and copies the model's per-lamella arrays [N]
    into numpy views of the message's own ``array('d')`` buffers. Safe because rclpy's
    ``publish`` serialises the message before it returns: refill it only after the previous
    ``publish`` call returned (one thread).
    """

    def __init__(self, msg_type):
        """Preallocate one ``msg_type`` (``ClutchEstimate``) message."""
        self.msg = msg_type()
        self._views: dict[str, np.ndarray] = {}  # numpy views on the message arrays [N]
        self._lamellas = -1

    def _resize(self, n: int) -> None:
        """Give the message float64 arrays of ``n`` lamellas (at start, or a new count)."""
        for name, _ in _FIELDS["float64[]"]:
            setattr(self.msg, name, array("d", bytes(8 * n)))
            # a view of the array the message holds (its setter may store a copy)
            self._views[name] = np.frombuffer(getattr(self.msg, name), dtype=np.float64)
        self._lamellas = n

    def fill(self, est, status, header):
        """Fill the message from a model ``Estimate`` and ``AdaptationStatus``; return it.

        ``header`` (the input RigState's) is referenced, not copied: the estimate carries the
        stamp of the sample it was computed from.
        """
        msg = self.msg
        n = len(est.lamella_normal_force)
        if n != self._lamellas:
            self._resize(n)
        views = self._views
        for name, attr in _FIELDS["float64[]"]:
            views[name][:] = getattr(est, attr)
        msg.header = header
        for name, attr in _FIELDS["float64"]:
            setattr(msg, name, float(getattr(est, attr)))
        for name, attr in _FIELDS["bool"]:
            setattr(msg, name, bool(getattr(est, attr)))
        for name, attr in _FIELDS["string"]:
            setattr(msg, name, getattr(est, attr))
        for name, kind, attr, state in _ADAPTATION:
            value = getattr(status, attr)
            if state:
                value = value == state
            setattr(msg, name, float(value) if kind == "float64" else bool(value))
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
