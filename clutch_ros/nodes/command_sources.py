"""Who publishes ``pressure_command``: publisher GIDs mapped to node names (can_bridge).

rclpy does not tell a subscriber the sender's name, but it gives the publisher's GID with
each message (``MessageInfo["publisher_gid"]``), and the graph
(``get_publishers_info_by_topic``) maps GIDs to node names.
"""

from __future__ import annotations

import time

from rclpy.node import Node

__all__ = ["CommandSources"]


class CommandSources:
    """Who publishes ``pressure_command``: publisher GIDs -> node names, from the ROS graph.

    ``wanted`` is the admitted source (a node name or fully qualified name; empty: any).
    :meth:`check` takes a message's ``MessageInfo`` and returns None to admit it, else why it
    is refused. The GID table is refreshed from ``get_publishers_info_by_topic`` when an
    unknown GID arrives (at most every ``REFRESH`` s) and by :meth:`diagnose` (1 Hz).
    """

    REFRESH = 0.2  # [s]

    def __init__(self, node: Node, wanted: str) -> None:
        self.node, self.wanted, self.topic = node, wanted.strip(), "pressure_command"
        self._names: dict[bytes, str] = {}
        self._next_refresh = 0.0
        self.publishers: list[str] = []
        self._sequence: dict[bytes, int] = {}  # publisher GID -> last sequence number
        #: commands that never reached the callback (overwritten in the queue), counted
        #: from the gaps in each publisher's sequence numbers
        self.superseded = 0

    def count_sequence(self, info) -> None:
        """Count the commands a publisher sent that this subscription never saw."""
        gid = info.get("publisher_gid") if isinstance(info, dict) else None
        number = info.get("publication_sequence_number") if isinstance(info, dict) else None
        if not gid or number is None:
            return
        key = bytes(gid["data"])
        last = self._sequence.get(key)
        if last is not None and number > last + 1:
            self.superseded += number - last - 1
        if len(self._sequence) < 64 or key in self._sequence:  # bounded
            self._sequence[key] = number

    def _refresh(self) -> None:
        infos = self.node.get_publishers_info_by_topic(self.topic)
        self._names = {bytes(i.endpoint_gid): _fqn(i.node_namespace, i.node_name)
                       for i in infos}
        self.publishers = sorted(self._names.values())
        self._next_refresh = time.monotonic() + self.REFRESH

    def check(self, info) -> str | None:
        """Return None when a message with MessageInfo ``info`` is admitted, else why not."""
        if not self.wanted:
            return None
        gid = (info or {}).get("publisher_gid") if isinstance(info, dict) else None
        if not gid:
            return "command refused: this rmw gives no publisher GID to check the source"
        key = bytes(gid["data"])
        name = self._names.get(key)
        if name is None and time.monotonic() >= self._next_refresh:
            self._refresh()
            name = self._names.get(key)
        if name is None:
            return "command refused: publisher not (yet) in the ROS graph"
        if name == self.wanted or name.rsplit("/", 1)[-1] == self.wanted:
            return None
        return f"command refused: from {name}, pump.command_source is {self.wanted}"

    def diagnose(self) -> dict:
        """Refresh the table; return the publishers as diagnostic values."""
        self._refresh()
        return {"commands_superseded": self.superseded,
                "command_publishers": ", ".join(self.publishers),
                "command_publisher_count": len(self.publishers),
                "command_source": self.wanted or "(any)"}


def _fqn(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"
