"""Who feeds a node, and which of them went silent: input ages named after the publishing nodes.

:class:`PeerWatch` keeps the arrival time of each input topic of a node and, when one is
missing or older than its timeout, says so naming the node(s) that publish it, read from the
ROS graph (``get_publishers_info_by_topic``): ``stale rig data: no rig_state from
/can_bridge for 0.31 s (> 0.25 s)``. When no node publishes the topic any more (the peer died
or was never started), the message names the node expected to (``no node publishes
rig_state (expected can_bridge)``). The graph is queried at most once per
``GRAPH_PERIOD_S`` per topic, and only while an input is silent.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ["GRAPH_PERIOD_S", "Input", "PeerWatch"]

GRAPH_PERIOD_S = 1.0  # [s] how long a list of publishers is reused


@dataclass
class Input:
    """One watched input: what it is called in messages, its topic, timeout and usual peer."""

    what: str  # e.g. "rig data"
    topic: str  # relative topic name, e.g. "rig_state"
    timeout: float  # [s]
    expected: str  # the node that normally publishes it, e.g. "can_bridge"
    last: float | None = None  # [s] node-clock time of the last arrival


class PeerWatch:
    """Arrival times of a node's inputs and the names of their publishers (see module doc)."""

    def __init__(self, node, inputs: list[Input]):
        self._node = node
        self.inputs = {i.what: i for i in inputs}
        self._peers: dict[str, tuple[float, str]] = {}

    def seen(self, what: str, now: float) -> None:
        """Record an arrival of input ``what`` at node-clock time ``now`` [s]."""
        self.inputs[what].last = now

    def set_timeout(self, what: str, timeout: float) -> None:
        """Change the timeout [s] of input ``what``."""
        self.inputs[what].timeout = timeout

    def publishers(self, topic: str) -> str:
        """Return the publishing nodes of ``topic`` (``/ns/name``, comma separated) or ''."""
        cached = self._peers.get(topic)
        now = time.monotonic()
        if cached is not None and now - cached[0] < GRAPH_PERIOD_S:
            return cached[1]
        try:
            infos = self._node.get_publishers_info_by_topic(
                self._node.resolve_topic_name(topic))
            names = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})
        except Exception:  # noqa: BLE001 - graph queries fail during shutdown
            names = []
        text = ", ".join(names)
        self._peers[topic] = (now, text)
        return text

    def describe(self, inp: Input, now: float) -> str:
        """Return why ``inp`` is silent at ``now`` [s], or '' when it is fresh."""
        if inp.last is not None and now - inp.last <= inp.timeout:
            return ""
        peers = self.publishers(inp.topic)
        source = f"from {peers}" if peers else \
            f"(no node publishes {inp.topic}; expected {inp.expected})"
        if inp.last is None:
            return f"no {inp.what}: nothing received on {inp.topic} yet {source}"
        age = now - inp.last
        return (f"stale {inp.what}: no {inp.topic} {source} for {age:.2f} s "
                f"(> {inp.timeout:g} s)")

    def silent(self, now: float) -> str:
        """Return the first silent input's description (in declaration order), or ''."""
        for inp in self.inputs.values():
            text = self.describe(inp, now)
            if text:
                return text
        return ""

    def ages(self, now: float) -> dict[str, float]:
        """Return ``{topic_age_s: age}`` [s] of every input (inf before the first)."""
        return {f"{i.topic}_age_s": (now - i.last if i.last is not None else float("inf"))
                for i in self.inputs.values()}
