"""QoS of the clutch topics after REP 2003 (see README.md, "QoS per topic").

Publishers are reliable (:func:`reliable_qos`), so a default subscriber receives them;
subscribers that only need the latest sample use :func:`sensor_qos` (best effort), which
receives from reliable and best-effort publishers alike.
"""

from __future__ import annotations

from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

__all__ = ["sensor_qos", "reliable_qos"]


def sensor_qos():
    """Return the sensor-data QoS profile (best effort, depth 5), for latest-sample readers."""
    return qos_profile_sensor_data


def reliable_qos(depth: int = 200):
    """Return a reliable, volatile QoS profile: estimates, commands and requests."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
