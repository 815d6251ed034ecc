"""ROS time stamps (builtin_interfaces/Time) to and from seconds [s].

The conversions themselves are :mod:`clutch_ros.interfaces`' (``stamp_to_s``, ``s_to_stamp``),
the ones the offline replay uses too; this module applies them to message objects.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time

from clutch_ros.interfaces import s_to_stamp, stamp_to_s

__all__ = ["stamp_to_sec", "sec_to_stamp"]


def stamp_to_sec(stamp) -> float:
    """Convert a builtin_interfaces/Time to seconds [s] (float; ``sec + nanosec * 1e-9``)."""
    return stamp_to_s(stamp.sec, stamp.nanosec)


def sec_to_stamp(seconds: float, stamp=None):
    """Fill (or create) a builtin_interfaces/Time from seconds [s]; NaN/negative give 0."""
    if stamp is None:
        stamp = Time()
    stamp.sec, stamp.nanosec = s_to_stamp(seconds)
    return stamp
