"""QoS of the clutch topics after REP 2003 (see README.md, "QoS per topic"), as rclpy profiles.

The profiles are written once, as plain data, in :data:`clutch_ros.interfaces.TOPICS`; this
module only builds rclpy ``QoSProfile`` objects from them (:func:`profile`) and reads a
discovered publisher's profile back (:func:`spec_of`, what the recorder stores in a bag).

Publishers are reliable (:func:`publisher_qos`), so a default subscriber receives them;
subscribers that only need the latest sample use :func:`sensor_qos` (best effort), which
receives from reliable and best-effort publishers alike.
"""

from __future__ import annotations

from typing import Any

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from clutch_ros import interfaces
from clutch_ros.interfaces import QosSpec

__all__ = ["profile", "publisher_qos", "reliable_qos", "sensor_qos", "spec_of",
           "subscriber_qos"]

#: ``RMW_DURATION_INFINITE`` [ns], what rmw reports for an unbounded duration.
_INFINITE_NS = 9223372036854775807
_UNSET = ("system_default", "unknown", "best_available")


def profile(spec: QosSpec) -> QoSProfile:
    """Return the rclpy ``QoSProfile`` of ``spec``.

    Durations left infinite and ``automatic`` liveliness keep rclpy's defaults, so
    ``profile(interfaces.SENSOR_DATA) == qos_profile_sensor_data``.
    """
    kwargs: dict[str, Any] = {}
    for key in ("deadline", "lifespan", "liveliness_lease_duration"):
        ns = getattr(spec, "liveliness_lease_ns" if key.startswith("liveliness") else
                     f"{key}_ns")
        if ns is not None:
            kwargs[key] = Duration(nanoseconds=ns)
    if spec.liveliness != "automatic":
        kwargs["liveliness"] = LivelinessPolicy[spec.liveliness.upper()]
    return QoSProfile(history=HistoryPolicy[spec.history.upper()], depth=spec.depth,
                      reliability=ReliabilityPolicy[spec.reliability.upper()],
                      durability=DurabilityPolicy[spec.durability.upper()], **kwargs)


def _topic(name: str) -> interfaces.Topic:
    found = interfaces.topic(name)
    if found is None:
        raise KeyError(f"{name!r} is not a clutch topic "
                       f"({', '.join(t.name for t in interfaces.TOPICS)})")
    return found


def publisher_qos(topic: str) -> QoSProfile:
    """Return the profile the publisher of clutch topic ``topic`` offers (the table's)."""
    return profile(_topic(topic).publisher)


def subscriber_qos(topic: str, depth: int | None = None) -> QoSProfile:
    """Return the default subscriber profile of clutch topic ``topic`` (``depth``: its own)."""
    spec = _topic(topic).subscriber
    return profile(spec if depth is None else spec.with_depth(depth))


def sensor_qos() -> QoSProfile:
    """Return the sensor-data QoS profile (best effort, depth 5), for latest-sample readers."""
    return profile(interfaces.SENSOR_DATA)


def reliable_qos(depth: int = 200) -> QoSProfile:
    """Return a reliable, volatile QoS profile: estimates, commands and requests."""
    return profile(interfaces.reliable(depth))


def _policy(value, fallback: str) -> str:
    name = value.name.lower()
    return fallback if name in _UNSET else name


def _ns(duration) -> int | None:
    ns = duration.nanoseconds
    return None if ns <= 0 or ns >= _INFINITE_NS else ns


def spec_of(offered: QoSProfile, fallback: QosSpec | None = None) -> QosSpec:
    """Return the :class:`~clutch_ros.interfaces.QosSpec` of a discovered publisher profile.

    ``offered`` is a ``TopicEndpointInfo.qos_profile`` (``get_publishers_info_by_topic``).
    DDS discovery does not carry the history: a publisher in another process reports it
    ``unknown`` with depth 0. Whatever it leaves unknown comes from ``fallback`` (the table's
    profile of a clutch topic); without one it stays as reported, as ``ros2 bag record``
    stores it. A zero or infinite duration is infinite (None).
    """
    base = fallback or QosSpec()
    history = offered.history.name.lower()
    if history in _UNSET and fallback is not None:
        history, depth = fallback.history, fallback.depth
    else:
        depth = int(offered.depth)
    return QosSpec(
        reliability=_policy(offered.reliability, base.reliability),
        durability=_policy(offered.durability, base.durability),
        depth=depth,
        history=history,
        deadline_ns=_ns(offered.deadline),
        lifespan_ns=_ns(offered.lifespan),
        liveliness=_policy(offered.liveliness, base.liveliness),
        liveliness_lease_ns=_ns(offered.liveliness_lease_duration),
    )
