"""Taking what DDS still queues for a node's subscriptions at shutdown, without an executor.

An executor spun at shutdown also runs the node's timers, so a recorder's own
``/diagnostics`` kept arriving and a "quiet for N s" drain never ended. Taking from the
subscriptions directly runs no timer, costs no task per message, and is bounded in time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["drain", "take"]

#: messages taken from one subscription in a row before the next one's turn.
TAKE_BATCH = 256
IDLE_SLEEP = 0.002  # [s] pause when no subscription had anything


def take(sub: Any, callback: Callable[..., None], limit: int = TAKE_BATCH) -> int:
    """Take up to ``limit`` queued messages of ``sub``, each into ``callback(data, info)``.

    ``sub`` is an rclpy subscription; its own raw/typed setting decides what ``data`` is.
    Returns the messages taken.
    """
    n = 0
    with sub.handle:
        while n < limit:
            item = sub.handle.take_message(sub.msg_type, sub.raw)
            if item is None:
                break
            callback(*item)
            n += 1
    return n


def drain(subs: Sequence[tuple[Any, Callable[..., None]]], quiet: float, limit: float,
          stop: Callable[[], bool] = lambda: False) -> int:
    """Take from every ``(subscription, callback)`` until all were empty for ``quiet`` [s].

    Ends after ``limit`` [s] at the latest, or as soon as ``stop()`` is true. Returns the
    messages taken.
    """
    start = time.monotonic()
    total, idle_since = 0, start
    while not stop():
        now = time.monotonic()
        if now - start >= limit or now - idle_since >= quiet:
            break
        taken = sum(take(sub, callback) for sub, callback in subs)
        if taken:
            total, idle_since = total + taken, time.monotonic()
        else:
            time.sleep(IDLE_SLEEP)
    return total
