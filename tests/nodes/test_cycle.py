"""Periodic jobs on a thread of their own (:mod:`clutch_ros.nodes.cycle`), on the real clock.

Only bounds that hold however busy the machine is are asserted: a job never runs more often
than its schedule allows (a window of T s holds at most T / period + 1 calls, also after a
stall), never after :meth:`Cycle.stop` returned, and goes on after an exception of a job; a
new period applies from the next call. Waits are for events (calls), bounded generously.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest

from clutch_ros.errors import ConfigError
from clutch_ros.nodes.cycle import Cycle

WAIT = 30.0  # [s] bound of a wait for calls (a loaded machine), never reached when healthy


def _wait_for(predicate, what: str) -> None:
    deadline = time.monotonic() + WAIT
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


def _errors() -> tuple[list, Callable[[str, BaseException], None]]:
    seen: list = []
    return seen, lambda name, err: seen.append((name, err))


def test_calls_never_exceed_the_schedule_and_stop_ends_them():
    stamps: dict[str, list[float]] = {"fast": [], "slow": []}
    seen, on_error = _errors()
    start = time.monotonic()
    cycle = Cycle("test_cycle", {
        "fast": (0.01, lambda: stamps["fast"].append(time.monotonic())),
        "slow": (0.05, lambda: stamps["slow"].append(time.monotonic()))}, on_error)
    cycle.start()
    _wait_for(lambda: len(stamps["fast"]) >= 30 and len(stamps["slow"]) >= 5, "30 + 5 calls")
    cycle.stop()
    end = time.monotonic()
    counts = {name: len(s) for name, s in stamps.items()}
    time.sleep(0.1)
    assert {name: len(s) for name, s in stamps.items()} == counts  # none after stop()
    assert not seen
    for name, period in (("fast", 0.01), ("slow", 0.05)):
        calls = stamps[name]
        assert calls[0] >= start + period  # never before its due time
        assert len(calls) <= (end - start) / period + 1, (name, len(calls))
        # any window: about its length / period calls (no burst after a late call; one more
        # for a call whose own start was delayed after its schedule was taken)
        for i in range(len(calls)):
            j = next((k for k in range(i, len(calls)) if calls[k] > calls[i] + 5 * period),
                     len(calls))
            assert j - i <= 5 + 2, (name, i, j - i)
        assert cycle.calls[name] == len(calls)


def test_a_stalled_job_skips_missed_periods_instead_of_bursting():
    calls: list[float] = []
    stall = threading.Event()

    def job():
        calls.append(time.monotonic())
        if len(calls) == 3:
            stall.wait(0.2)  # 20 periods late

    seen, on_error = _errors()
    cycle = Cycle("test_stall", {"job": (0.01, job)}, on_error).start()
    _wait_for(lambda: len(calls) >= 10, "10 calls")
    cycle.stop()
    resumed = calls[3] - calls[2]
    assert resumed >= 0.2  # (the stall)
    # after the stall: one call, then the schedule again, never a catch-up burst
    assert all(b - a > 0.0 for a, b in zip(calls, calls[1:]))
    window = [t for t in calls if calls[3] <= t <= calls[3] + 0.05]
    assert len(window) <= 0.05 / 0.01 + 2, window


def test_an_exception_is_reported_and_the_cycle_goes_on():
    calls: list[int] = []
    seen, on_error = _errors()

    def job():
        calls.append(1)
        if len(calls) <= 3:
            raise RuntimeError(f"bad call {len(calls)}")

    cycle = Cycle("test_errors", {"job": (0.01, job)}, on_error).start()
    _wait_for(lambda: len(calls) >= 6, "calls after the exceptions")
    cycle.stop()
    assert [name for name, _ in seen] == ["job"] * 3
    assert [str(err) for _, err in seen] == ["bad call 1", "bad call 2", "bad call 3"]


def test_a_new_period_applies_from_the_next_call():
    calls: list[float] = []
    seen, on_error = _errors()
    cycle = Cycle("test_period", {"job": (0.01, lambda: calls.append(time.monotonic()))},
                  on_error).start()
    _wait_for(lambda: len(calls) >= 3, "3 calls")
    cycle.set_period("job", 0.5)
    changed = time.monotonic()
    assert cycle.period("job") == 0.5
    time.sleep(0.3)
    after = [t for t in calls if t > changed]
    assert len(after) <= 1, after  # at most the one already due; then one per 0.5 s
    cycle.set_period("job", 0.01)  # and back: calls resume at once
    n = len(calls)
    _wait_for(lambda: len(calls) >= n + 5, "calls at the short period again")
    cycle.stop()
    assert not seen


@pytest.mark.parametrize("period", [0.0, -0.01, float("nan"), float("inf")])
def test_a_bad_period_is_refused(period):
    with pytest.raises(ConfigError, match="period must be > 0 s"):
        Cycle("bad", {"job": (period, lambda: None)}, lambda *_: None)
    cycle = Cycle("ok", {"job": (0.01, lambda: None)}, lambda *_: None)
    with pytest.raises(ConfigError, match="period must be > 0 s"):
        cycle.set_period("job", period)
