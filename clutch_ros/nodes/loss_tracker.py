"""Recording bookkeeping (no rclpy): what arrived, what was written, what was lost.

A recorder cannot see a message that never reached it, but DDS numbers every sample a
publisher (DDS writer) sends: rclpy hands the ``publication_sequence_number`` and the
``publisher_gid`` to a subscription callback that takes a ``MessageInfo``. Within one
publisher the numbers are consecutive, so a jump from ``s`` to ``s + 1 + k`` means ``k``
samples were lost on the way (best-effort transport, an overflowing reader queue, or a
KEEP_LAST publisher overwriting unacknowledged samples). :class:`LossTracker` counts those
gaps per topic, exactly, and separately the samples a publisher had sent before the recorder
saw its first one (``missed_at_start``: sent before the recorder matched it, or before it
started).

What it cannot see: samples lost after the last one received from a publisher (a gap shows
only when a later sample arrives), and loss on middleware that gives no sequence numbers
(``tracked`` is False then).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["LossTracker", "TopicStats", "format_counts", "parse_counts"]


@dataclass
class TopicStats:
    """Counts of one recorded topic [messages]."""

    received: int = 0
    dropped: int = 0  # gaps in the publishers' sequence numbers
    missed_at_start: int = 0  # sent by a publisher before its first sample seen here
    untracked: int = 0  # received without a sequence number (no loss detection)
    publishers: int = 0  # distinct publishers seen


@dataclass
class LossTracker:
    """Count received and lost samples per topic from DDS publication sequence numbers."""

    topics: dict[str, TopicStats] = field(default_factory=dict)
    _last: dict[tuple[str, bytes], int] = field(default_factory=dict)

    def add_topic(self, topic: str) -> None:
        """Start counting ``topic`` (absolute name)."""
        self.topics.setdefault(topic, TopicStats())

    def received(self, topic: str, info: Mapping[str, Any] | None) -> int:
        """Account for one sample of ``topic`` with its rclpy ``MessageInfo``.

        Returns:
            the number of samples found lost just before this one (0 normally).

        """
        stats = self.topics.setdefault(topic, TopicStats())
        stats.received += 1
        seq = info.get("publication_sequence_number") if info else None
        gid = info.get("publisher_gid") if info else None
        if seq is None or not gid:
            stats.untracked += 1
            return 0
        key = (topic, bytes(gid.get("data", b"")) if isinstance(gid, Mapping) else bytes(gid))
        last = self._last.get(key)
        if last is None:
            stats.publishers += 1
            stats.missed_at_start += max(int(seq) - 1, 0)
            self._last[key] = int(seq)
            return 0
        gap = int(seq) - last - 1
        if gap < 0:  # a repeated or older sample: no gap, keep the newest
            return 0
        self._last[key] = int(seq)
        stats.dropped += gap
        return gap

    @property
    def tracked(self) -> bool:
        """True when every sample so far carried a sequence number."""
        return not any(s.untracked for s in self.topics.values())

    def counts(self, what: str) -> dict[str, int]:
        """Return ``{topic: count}`` of one :class:`TopicStats` field."""
        return {topic: getattr(stats, what) for topic, stats in self.topics.items()}


def format_counts(counts: Mapping[str, int]) -> str:
    """Format ``{"/a": 1, "/b": 2}`` as ``"/a=1,/b=2"`` (the bag custom_data format)."""
    return ",".join(f"{topic}={n}" for topic, n in sorted(counts.items()))


def parse_counts(text: str) -> dict[str, int]:
    """Inverse of :func:`format_counts`."""
    out = {}
    for part in filter(None, (text or "").split(",")):
        topic, _, n = part.rpartition("=")
        out[topic] = int(n)
    return out
