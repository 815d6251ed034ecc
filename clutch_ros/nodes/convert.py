"""Conversions to rclpy messages: model estimates, CAN rig samples and raw frames."""

from __future__ import annotations

import math
from array import array

import numpy as np
from clutch_msgs.msg import CanFrame, RigState

from clutch_ros.interfaces import ESTIMATE_FIELDS
from clutch_ros.nodes.stamps import sec_to_stamp
from clutch_ros.rigstate import fill_msg

__all__ = ["EstimateMessage", "can_frame_to_ros", "rig_state_to_ros"]


#: (message field, Estimate attribute) of the per-lamella arrays
_ARRAYS = tuple((f.name, f.attr) for f in ESTIMATE_FIELDS if f.kind == "float64[]")


def _compile_scalar_filler():
    """Return ``fill(msg, est, status)`` setting every scalar field of the table.

    The table is compiled once into straight-line assignments (``msg.modelled_torque =
    float(est.modelled_torque)`` ...): a loop of ``setattr``/``getattr`` over it cost about
    twice the hand-written assignments, 5-10 us per estimate on the node's hot path.
    """
    convert = {"float64": "float", "bool": "bool", "string": "str"}
    lines = ["def fill(msg, est, status):"]
    for f in ESTIMATE_FIELDS:
        if f.kind == "float64[]" or f.source == "uncertainty":  # set by the node itself
            continue
        # identifiers of the constant table only, never data
        assert f.name.isidentifier() and f.attr.isidentifier(), f
        assert not f.state or f.state.isidentifier(), f
        value = f"{'est' if f.source == 'estimate' else 'status'}.{f.attr}"
        if f.state:
            value = f"{value} == {f.state!r}"
        lines.append(f"    msg.{f.name} = {convert[f.kind]}({value})")
    namespace: dict = {}
    exec("\n".join(lines), namespace)
    return namespace["fill"]


_fill_scalars = _compile_scalar_filler()


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
        for name, _ in _ARRAYS:
            setattr(self.msg, name, array("d", bytes(8 * n)))
            # a view of the array the message holds (its setter may store a copy)
            self._views[name] = np.frombuffer(getattr(self.msg, name), dtype=np.float64)
        self._lamellas = n

    def fill(self, est, status, header, torque_std=math.nan):
        """Fill the message from a model ``Estimate`` and ``AdaptationStatus``; return it.

        ``header`` (the input RigState's) is referenced, not copied: the estimate carries the
        stamp of the sample it was computed from. ``torque_std``: ``modelled_torque_std``
        [N m] (:class:`clutch_ros.model.uncertainty.TorqueStd`).
        """
        msg = self.msg
        n = len(est.lamella_normal_force)
        if n != self._lamellas:
            self._resize(n)
        views = self._views
        for name, attr in _ARRAYS:
            views[name][:] = getattr(est, attr)
        msg.header = header
        _fill_scalars(msg, est, status)
        msg.modelled_torque_std = float(torque_std)
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
