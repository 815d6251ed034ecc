"""Real-time options of a node process: scheduling policy and priority, CPU affinity, locked memory.

A rig PC (often a PREEMPT_RT kernel) also runs the test automation, a logger and a dashboard.
Under the normal time-sharing policy a busy machine delays the live chain; its commands then
arrive late and the closed loop overshoots. Every node therefore takes four read-only
parameters, applied once at start to every thread of its process (the DDS and CAN threads
that exist by then, and so, by inheritance, the threads made later):

``rt.policy``        ``other`` (default, SCHED_OTHER: nothing changes), ``fifo`` (SCHED_FIFO) or
                     ``rr`` (SCHED_RR)
``rt.priority``      static priority of ``fifo``/``rr``, 1..99 (higher preempts lower)
``rt.cpus``          CPU affinity, ``"0,2-3"`` or one integer; empty: every CPU
``rt.lock_memory``   ``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page fault on a hot path

Where the OS refuses (no CAP_SYS_NICE, ``ulimit -r`` 0, a memory-lock limit, a CPU that does
not exist), the node logs one WARN line with the reason, publishes it as a WARN status
``<node>/realtime`` on ``/diagnostics`` and runs on without it: a real-time option never stops
a node. Linux only; elsewhere each requested option is reported as refused.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass, field

from rcl_interfaces.msg import ParameterDescriptor

from clutch_ros.nodes.parameters import ParamSpec

__all__ = ["REALTIME_PARAMS", "RealtimeSettings", "RealtimeReport", "apply_realtime",
           "declare_realtime", "parse_cpus", "policy_of", "time_sharing"]

_POLICIES = {"other": "SCHED_OTHER", "fifo": "SCHED_FIFO", "rr": "SCHED_RR"}
_MCL_CURRENT, _MCL_FUTURE = 1, 2  # sys/mman.h (Linux)
_AT_START = "read-only: applied once at start"

#: The real-time parameters every node declares (listed by its ``--help``).
REALTIME_PARAMS = [
    ParamSpec("rt.policy", "other", "scheduling policy of every thread of the node's process: "
              "other (time-sharing), fifo (SCHED_FIFO) or rr (SCHED_RR); refused by the OS: a "
              f"WARN and the node runs on; {_AT_START}", choices=tuple(_POLICIES),
              read_only=True),
    ParamSpec("rt.priority", 50, f"static priority of fifo/rr (higher preempts lower); {_AT_START}",
              "", 1, 99, read_only=True),
    ParamSpec("rt.cpus", "", "CPU affinity of the process: CPU numbers and ranges such as "
              f"'0,2-3' (or one integer); empty: every CPU; {_AT_START}", read_only=True),
    ParamSpec("rt.lock_memory", False, "lock the process's memory (mlockall current and "
              f"future pages): no page faults on hot paths; {_AT_START}", read_only=True),
]


def parse_cpus(value: object) -> frozenset[int]:
    """Return the CPU set of an ``rt.cpus`` value (``""``, ``3``, ``"0,2-3"``); else ValueError."""
    if isinstance(value, bool):
        raise ValueError(f"rt.cpus: expected CPU numbers such as '0,2-3', got {value!r}")
    if isinstance(value, int):
        items = [str(value)]
    elif isinstance(value, str):
        items = [part.strip() for part in value.split(",") if part.strip()]
    else:
        raise ValueError(f"rt.cpus: expected CPU numbers such as '0,2-3', got {value!r}")
    cpus: set[int] = set()
    for item in items:
        low, _, high = item.partition("-")
        try:
            first, last = int(low), int(high or low)
        except ValueError:
            raise ValueError(f"rt.cpus: {item!r} is no CPU number or range (such as 0,2-3)") \
                from None
        if first < 0 or last < first:
            raise ValueError(f"rt.cpus: {item!r} is no CPU number or range (such as 0,2-3)")
        cpus.update(range(first, last + 1))
    return frozenset(cpus)


@dataclass(frozen=True)
class RealtimeSettings:
    """What a node asked for: policy name, priority (1..99), CPUs (empty: all), memory lock."""

    policy: str = "other"
    priority: int = 50
    cpus: frozenset[int] = frozenset()
    lock_memory: bool = False

    @property
    def requested(self) -> bool:
        """True when any option departs from the operating system's defaults."""
        return self.policy != "other" or bool(self.cpus) or self.lock_memory


@dataclass
class RealtimeReport:
    """What :func:`apply_realtime` did: ``applied`` and ``refused`` options, with reasons."""

    applied: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)

    @property
    def level(self) -> str:
        """``OK`` when every requested option was applied, else ``WARN``."""
        return "WARN" if self.refused else "OK"

    def message(self) -> str:
        """One line for the log and the diagnostics status."""
        if self.refused:
            applied = f"; applied: {', '.join(self.applied)}" if self.applied else ""
            return "real-time options refused: " + "; ".join(self.refused) + applied
        return "real-time options applied: " + (", ".join(self.applied) or "none requested")


def declare_realtime(node) -> RealtimeSettings:
    """Declare :data:`REALTIME_PARAMS` on ``node`` and return its settings (ValueError if bad).

    ``rt.cpus`` is dynamically typed, so ``-p rt.cpus:=0`` and a launch file's ``value="0"``
    (both read as an integer by ROS) work as well as ``'0,2-3'``.
    """
    values = {}
    for spec in REALTIME_PARAMS:
        descriptor = ParameterDescriptor(description=spec.describe(), read_only=True,
                                         dynamic_typing=spec.name == "rt.cpus")
        values[spec.name] = node.declare_parameter(spec.name, spec.default, descriptor).value
    policy = values["rt.policy"]
    if policy not in _POLICIES:
        raise ValueError(f"rt.policy: expected one of {', '.join(_POLICIES)}, got {policy!r}")
    priority = values["rt.priority"]
    if isinstance(priority, bool) or not isinstance(priority, int) or not 1 <= priority <= 99:
        raise ValueError(f"rt.priority: expected an integer 1..99, got {priority!r}")
    lock = values["rt.lock_memory"]
    if not isinstance(lock, bool):
        raise ValueError(f"rt.lock_memory: expected true or false, got {lock!r}")
    return RealtimeSettings(policy, priority, parse_cpus(values["rt.cpus"]), lock)


def _threads() -> list[int]:
    """Thread ids of this process (Linux: /proc/self/task), else the process id alone."""
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return [os.getpid()]


def apply_realtime(settings: RealtimeSettings) -> RealtimeReport:
    """Apply ``settings`` to every thread of this process; never raises for a refusal."""
    report = RealtimeReport()
    if not settings.requested:
        return report
    threads = _threads()
    if settings.cpus:
        try:
            for tid in threads:
                os.sched_setaffinity(tid, settings.cpus)
            report.applied.append("cpus " + ",".join(map(str, sorted(settings.cpus))))
        except (OSError, AttributeError) as err:
            report.refused.append(f"cpus {sorted(settings.cpus)}: {_reason(err)}")
    if settings.policy != "other":
        name = _POLICIES[settings.policy]
        try:
            policy = getattr(os, name)
            for tid in threads:
                os.sched_setscheduler(tid, policy, os.sched_param(settings.priority))
            report.applied.append(f"{name} priority {settings.priority}")
        except (OSError, AttributeError) as err:
            report.refused.append(f"{name} priority {settings.priority}: {_reason(err)} "
                                  "(needs CAP_SYS_NICE or an rtprio limit, ulimit -r)")
    if settings.lock_memory:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
                raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
            report.applied.append("memory locked")
        except (OSError, AttributeError) as err:
            report.refused.append(f"memory lock: {_reason(err)} (needs CAP_IPC_LOCK or "
                                  "ulimit -l unlimited)")
    return report


def time_sharing() -> None:
    """Put every thread of this process back on the normal time-sharing policy (SCHED_OTHER)."""
    for tid in _threads():
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError):
            pass  # a thread that ended meanwhile, or no such call: nothing to undo


def policy_of(pid: int) -> str:
    """Return the scheduling policy of process ``pid``'s main thread (``other``, ``fifo``, ...)."""
    try:
        policy = os.sched_getscheduler(pid)
    except (OSError, AttributeError):
        return "unknown"
    names = {getattr(os, value, None): key for key, value in _POLICIES.items()}
    return names.get(policy, "other")


def _reason(err: BaseException) -> str:
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    return str(err) or type(err).__name__
