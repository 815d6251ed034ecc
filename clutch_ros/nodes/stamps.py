"""ROS time stamps (builtin_interfaces/Time) to and from seconds [s]."""

from __future__ import annotations

import math

from builtin_interfaces.msg import Time

__all__ = ["stamp_to_sec", "sec_to_stamp"]


def stamp_to_sec(stamp) -> float:
    """Convert a builtin_interfaces/Time to seconds [s] (float)."""
    return stamp.sec + stamp.nanosec * 1e-9


def sec_to_stamp(seconds: float, stamp=None):
    """Fill (or create) a builtin_interfaces/Time from seconds [s]; NaN/negative give 0."""
    if stamp is None:
        stamp = Time()
    if not math.isfinite(seconds) or seconds < 0.0:
        seconds = 0.0
    ns = int(round(seconds * 1e9))
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
    return stamp
