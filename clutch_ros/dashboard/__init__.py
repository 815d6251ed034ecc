"""The live dashboard: the clutch topics on a Foxglove WebSocket server (foxglove-sdk).

Layer: above :mod:`clutch_ros.offline` (the replay) and :mod:`clutch_ros.bag`, below the nodes; no
rclpy here. The live ``dashboard`` node (:mod:`clutch_ros.nodes.dashboard`) forwards the bytes
ROS delivers; ``clutch dashboard --bag`` plays a bag (:class:`BagStream`, :class:`BagPlayer`).

- :mod:`~clutch_ros.dashboard.topics`: served topics, ``ros2msg`` schema text.
- :mod:`~clutch_ros.dashboard.server`: :class:`DashboardServer` (channels, slow clients,
  health figures).
- :mod:`~clutch_ros.dashboard.bag_stream`: a bag as a message stream, estimates computed
  with the offline replay when the bag has none.
- :mod:`~clutch_ros.dashboard.player`: real-time (× rate) playback with ``/diagnostics``.
- :mod:`~clutch_ros.dashboard.playback`: the player's clock under client control (pause,
  seek, speed).
- :mod:`~clutch_ros.dashboard.sdk_listener`: the SDK's callbacks, handed to plain handlers.
- :mod:`~clutch_ros.dashboard.parameters`: ``/node.parameter`` names; the bag's read-only set.
- :mod:`~clutch_ros.dashboard.client_publish`: the client-publish whitelist and decoding.
- :mod:`~clutch_ros.dashboard.errors`: :class:`DashboardError`.
"""

from clutch_ros.dashboard.bag_stream import BagStream, estimate_frames
from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.parameters import ReadOnlyParameters, split_name
from clutch_ros.dashboard.playback import PlaybackClock
from clutch_ros.dashboard.player import BagPlayer, diagnostic_array_cdr
from clutch_ros.dashboard.server import (
    DEFAULT_BACKLOG,
    DEFAULT_HOST,
    DEFAULT_PORT,
    DashboardServer,
    absolute,
)
from clutch_ros.dashboard.topics import TOPICS, DashboardTopic, message_definition

__all__ = [
    "DEFAULT_BACKLOG",
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "TOPICS",
    "BagPlayer",
    "BagStream",
    "DashboardError",
    "DashboardServer",
    "DashboardTopic",
    "PlaybackClock",
    "ReadOnlyParameters",
    "absolute",
    "diagnostic_array_cdr",
    "estimate_frames",
    "message_definition",
    "split_name",
]
