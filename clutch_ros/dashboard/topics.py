"""The topics the dashboard serves and their Foxglove channel schemas.

Every channel is advertised with message encoding ``cdr``, schema encoding ``ros2msg``, the
ROS 2 type name as schema name (``clutch_msgs/msg/RigState``,
``diagnostic_msgs/msg/DiagnosticArray``) and the full message definition with its
dependencies, concatenated the way rosbag2's MCAP storage writes it::

    <definition of the type itself>
    ================================================================================
    MSG: std_msgs/Header
    <definition of the dependency>
    ...

The text comes from the same call rosbags' rosbag2 writer makes for its MCAP schemas
(``Typestore.generate_msgdef(typename, ros_version=2)``) on the package's typestore, whose
``clutch_msgs`` types are parsed from ``msg_defs/msg/*.msg``; a bag written by
:mod:`clutch_ros.bag.writer` therefore carries byte-identical schema text. Foxglove (and any
client: ``rosbags.typesys.get_types_from_msg`` parses it) decodes the CDR payloads with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from clutch_ros import interfaces
from clutch_ros.bag.typestore import Typestore, clutch_typestore, msg_class

__all__ = [
    "DIAGNOSTIC_ARRAY",
    "SCHEMA_ENCODING",
    "MESSAGE_ENCODING",
    "TOPICS",
    "DashboardTopic",
    "message_definition",
]

DIAGNOSTIC_ARRAY = interfaces.DIAGNOSTICS.typename
#: Foxglove message encoding of every channel: the bytes ROS publishes and rosbag2 stores.
MESSAGE_ENCODING = "cdr"
#: Foxglove schema encoding of every channel: ROS 2 ``.msg`` text.
SCHEMA_ENCODING = "ros2msg"


@dataclass(frozen=True)
class DashboardTopic:
    """One served topic.

    Attributes:
        name: topic name as the nodes use it (relative unless absolute, e.g. ``rig_state``,
            ``/diagnostics``); channels are advertised under the resolved absolute name.
        typename: ROS 2 type name, e.g. ``clutch_msgs/msg/RigState``.
        sensor_data: subscribe with sensor-data QoS (best effort) in live mode; otherwise
            reliable (the topic's subscriber QoS in :data:`clutch_ros.interfaces.TOPICS`).

    """

    name: str
    typename: str
    sensor_data: bool = False


#: The topics of the dashboard, in the order the channels are advertised: every clutch
#: topic of :data:`clutch_ros.interfaces.TOPICS`, subscribed with its default subscriber QoS
#: (``can_frames`` carries data only while the bridge publishes raw frames).
TOPICS: tuple[DashboardTopic, ...] = tuple(
    DashboardTopic(t.name, t.typename,
                   sensor_data=t.subscriber.reliability == interfaces.BEST_EFFORT)
    for t in interfaces.TOPICS
)


def message_definition(typename: str, store: Typestore | None = None) -> str:
    """Return the ``ros2msg`` schema text of ``typename`` as rosbag2's MCAP storage writes it.

    Args:
        typename: ROS 2 type name (``clutch_msgs/msg/ClutchEstimate``).
        store: typestore (default :func:`~clutch_ros.bag.typestore.clutch_typestore`).

    Raises:
        UnknownTypeError: the type is not registered.

    """
    store = store or clutch_typestore()
    msg_class(typename, store)  # a clear UnknownTypeError instead of rosbags' KeyError
    return _definition(store, typename)


@lru_cache(maxsize=64)
def _definition(store: Typestore, typename: str) -> str:
    """Return the cached ``generate_msgdef`` text (the call rosbags' rosbag2 MCAP writer makes)."""
    text, _ = store.generate_msgdef(typename, ros_version=2)
    return text
