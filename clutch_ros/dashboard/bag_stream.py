"""A recorded bag as the dashboard's message stream, with ClutchEstimates computed on the fly.

:class:`BagStream` yields ``(time_ns, topic, cdr_bytes)`` in bag-time order for every message
of the bag on a topic the dashboard serves (the bag's raw bytes, never re-serialized). When
the bag holds ``RigState`` but no ``/clutch_estimate`` (a rig recording), the estimator's
model is run over the RigState stream first with the offline replay
(:func:`clutch_ros.offline.replay.replay_bag`, identical to the live estimator node) and each
published estimate is inserted right after its input sample, serialized exactly as
``clutch replay -o`` writes it (:func:`estimate_frames`): same header stamp and frame id,
same bytes.

Nothing is held per message: the bag is read lazily and the estimates are serialized in
blocks from the replay's arrays, so an hour-long 1 kHz bag streams in bounded memory (the
replay's numpy columns aside).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros import interfaces
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.typestore import CLUTCH_ESTIMATE_TYPE, RIG_STATE_TYPE
from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.server import absolute
from clutch_ros.dashboard.topics import TOPICS, DashboardTopic
from clutch_ros.offline.replay import estimate_layout

__all__ = ["BagStream", "estimate_frames"]

_BLOCK = 4096


def estimate_frames(result: Any, block: int = _BLOCK, first_row: int = 0
                    ) -> Iterator[tuple[int, int, bytes]]:
    """Yield ``(row, stamp_ns, cdr)`` for each ClutchEstimate ``clutch replay -o`` writes.

    Args:
        result: a :class:`~clutch_ros.offline.replay.ReplayResult`.
        block: messages serialized per numpy block.
        first_row: skip the estimates of input rows before this one.

    ``row`` indexes the replay's RigState arrays (the input sample), ``stamp_ns`` is its header
    stamp [ns since epoch]; the bytes equal those :func:`~clutch_ros.offline.replay.write_estimates`
    stores for that sample.

    """
    serializer, rows, stamps, columns = estimate_layout(result)
    size = serializer.size
    skip = int(np.searchsorted(rows, first_row, side="left"))
    for first in range(skip, len(rows), block):
        last = min(first + block, len(rows))
        part = {k: v[first:last] for k, v in columns.items()}
        data = serializer.serialize_stamped(stamps[first:last], part).tobytes()
        for i in range(last - first):
            yield int(rows[first + i]), int(stamps[first + i]), data[i * size : (i + 1) * size]


class BagStream:
    """The served topics of one bag, as a time-ordered stream of CDR messages.

    Args:
        bag: bag directory or storage file.
        params: estimator parameters (``ClutchParams``), used when estimates are computed.
        topics: the dashboard's topics (default :data:`~clutch_ros.dashboard.topics.TOPICS`);
            bag topics are matched by absolute name (``/rig_state``) and type.
        namespace: ROS namespace relative topic names resolve in (default ``/``).

    Attributes:
        topics: absolute name -> type of every topic the stream yields.
        computed: True when the ClutchEstimates are computed from the RigState stream.
        start_ns, end_ns: first and last time of the stream [ns since epoch].
        counts: messages per topic the stream yields [messages].

    Raises:
        DashboardError: the bag holds none of the served topics.
        BagError: the bag cannot be read (see :class:`~clutch_ros.bag.reader.BagReader`).

    """

    def __init__(
        self,
        bag: str | Path,
        params: Any,
        *,
        topics: tuple[DashboardTopic, ...] = TOPICS,
        namespace: str = "/",
    ):

        self.path = Path(bag)
        wanted = {absolute(t.name, namespace): t.typename for t in topics}
        with BagReader(self.path) as reader:
            have = reader.topics
        self._raw = sorted(
            name for name, info in have.items() if wanted.get(name) == info.typename
        )
        if not self._raw:
            listed = ", ".join(f"{n} ({i.typename})" for n, i in sorted(have.items())) or "none"
            raise DashboardError(
                f"{self.path}: no topic the dashboard serves (it serves "
                f"{', '.join(wanted)}; the bag has {listed})"
            )
        self.topics = {name: have[name].typename for name in self._raw}
        self.counts = {name: have[name].count for name in self._raw}
        est_topic = absolute(interfaces.CLUTCH_ESTIMATE.name, namespace)
        rig_topic = absolute(interfaces.RIG_STATE.name, namespace)
        self._estimates = None
        self.computed = (
            est_topic in wanted and est_topic not in self.topics and rig_topic in self.topics
        )
        if self.computed:
            from clutch_ros.offline.replay import published_rows, replay_bag

            result = replay_bag(self.path, params, topic=rig_topic)
            self._estimates = result
            self._est_topic = est_topic
            self.topics[est_topic] = CLUTCH_ESTIMATE_TYPE
            self.counts[est_topic] = int(published_rows(result.batch).sum())
            self._rig_times = np.asarray(result.rig.bag_time_ns, dtype=np.int64)
        self.rig_topic = rig_topic if self.topics.get(rig_topic) == RIG_STATE_TYPE else None
        with BagReader(self.path) as reader:
            self.start_ns, self.end_ns = reader.start_ns, reader.end_ns

    def __iter__(self) -> Iterator[tuple[int, str, bytes]]:
        """Yield ``(time_ns, topic, cdr)`` of the whole bag (see :meth:`messages`)."""
        return self.messages()

    def messages(self, start_ns: int | None = None) -> Iterator[tuple[int, str, bytes]]:
        """Yield ``(time_ns, topic, cdr)`` in time order (an estimate right after its input).

        Args:
            start_ns: first bag time to yield [ns since epoch] (None: the start). The
                estimates were computed over the whole bag from its start, so those from a
                later position are the ones of a whole pass (``clutch replay -o``'s).

        ``time_ns`` is the bag (receive) time [ns since epoch]; for a computed estimate it is
        the bag time of its RigState input.
        """
        with BagReader(self.path) as reader:
            raw = (
                (int(m.timestamp_ns), 0, m.topic, bytes(m.msg))
                for m in reader.messages(self._raw, raw=True, start_ns=start_ns)
            )
            streams: list[Iterator[tuple[int, int, str, bytes]]] = [raw]
            if self._estimates is not None:
                streams.append(self._computed(start_ns))
            for time_ns, _, topic, data in heapq.merge(*streams, key=lambda m: (m[0], m[1])):
                yield time_ns, topic, data

    def _computed(self, start_ns: int | None) -> Iterator[tuple[int, int, str, bytes]]:
        times = self._rig_times
        topic = self._est_topic
        first = 0 if start_ns is None else int(np.searchsorted(times, start_ns, side="left"))
        for row, _, data in estimate_frames(self._estimates, first_row=first):
            yield int(times[row]), 1, topic, data
