"""Periodic work of a node on a thread of its own instead of ROS timers (wall-clock nodes).

Why: every timer call costs an executor wake-up, and an rclpy wake-up (the wait set of the
node's every service, subscription, timer and QoS event handler filled and waited on, the
ready entities read back) costs ~0.27 ms of CPU even with the lean executor (``python -m
benchmarks.wakeup_probe``, ``timer`` row). A plain thread that sleeps until the next due time
wakes for a fraction of that (figures of ``python -m benchmarks.live_cpu`` in
benchmarks/RESULTS.md). Users: the can_bridge's PumpRequest cycle and flush (120 of its ~220
executor wake-ups per second before) and the controller's step with the ``timer`` trigger.
Nodes on simulated time (``use_sim_time``) keep ROS timers: only those follow ``/clock``.

:class:`Cycle` runs named jobs, each every ``period`` [s] on the monotonic clock, on one
daemon thread. The schedule is a timer's (as rcl's): a job is due one period after its
previous due time, so the mean rate is exactly ``1 / period``; a job that fell more than a
period behind skips the missed calls (keeping its phase) instead of bursting. A job runs at
the first wake-up at or after its due time, never before: a window of ``T`` seconds holds at
most ``T / period + 1`` calls. :meth:`Cycle.set_period` applies a new period at once (the
next call is due one new period after the previous call). An exception of a job is handed to
``on_error`` and the cycle goes on (the node logs it; a stopped cycle would leave the pump
without requests). :meth:`Cycle.stop` returns after the thread ended: no job runs after it
(the bridge sends its last 0 bar frame only then).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from clutch_ros.errors import ConfigError

__all__ = ["Cycle"]


@dataclass
class _Job:
    period: float  # [s]
    run: Callable[[], object]
    due: float  # [s] monotonic
    last: float  # [s] monotonic, the previous due time (the start for the first call)


class Cycle:
    """Periodic jobs on one thread (see the module docstring).

    ``jobs``: ``{name: (period [s], callable)}``; ``on_error(name, exception)`` is called on
    the thread for an exception of a job; ``clock`` returns monotonic seconds.
    """

    def __init__(self, name: str, jobs: Mapping[str, tuple[float, Callable[[], object]]],
                 on_error: Callable[[str, BaseException], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        for job, (period, _run) in jobs.items():
            _check_period(job, period)
        now = clock()
        self._jobs = {job: _Job(period, run, now + period, now)
                      for job, (period, run) in jobs.items()}
        self._on_error, self._clock = on_error, clock
        self._wake = threading.Event()
        self._stopped = False
        self._lock = threading.Lock()  # the schedule: the thread and set_period
        #: calls made per job (tests and diagnostics read it)
        self.calls = dict.fromkeys(jobs, 0)
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)

    def start(self) -> Cycle:
        """Start the thread; return self."""
        self._thread.start()
        return self

    def set_period(self, job: str, period: float) -> None:
        """Run ``job`` every ``period`` [s] from now on (due one period after its last call)."""
        _check_period(job, period)
        with self._lock:
            entry = self._jobs[job]
            entry.period = period
            entry.due = entry.last + period
        self._wake.set()

    def period(self, job: str) -> float:
        """Return the period [s] of ``job``."""
        return self._jobs[job].period

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread and wait (up to ``timeout`` [s]) until it has ended."""
        self._stopped = True
        self._wake.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _loop(self) -> None:
        jobs, clock, wake = self._jobs, self._clock, self._wake
        while not self._stopped:
            with self._lock:
                wait = min(job.due for job in jobs.values()) - clock()
            if wait > 0.0:
                if wake.wait(wait):
                    wake.clear()
                continue  # (re-read the schedule: a new period, or stop)
            for name, job in jobs.items():
                with self._lock:
                    now = clock()
                    if job.due > now or self._stopped:
                        continue
                    job.last = job.due
                    # the next due time, skipping whole periods missed (phase kept)
                    behind = math.floor((now - job.due) / job.period)
                    job.due += (behind + 1) * job.period
                self.calls[name] += 1
                try:
                    job.run()
                except Exception as err:  # noqa: BLE001 - reported; the cycle must go on
                    self._on_error(name, err)


def _check_period(job: str, period: float) -> None:
    if not (math.isfinite(period) and period > 0.0):
        raise ConfigError(f"cycle job {job!r}: period must be > 0 s, got {period!r}")
