"""What else used the machine while a benchmark ran: CPU outside the benchmark's processes.

A CPU figure is only comparable with another one taken on an equally quiet machine: a busy
loop left behind by an interrupted test run, or another tenant of the VM (``steal``), moves
the bare echo node's figure by a third and the chain's with it. :class:`MachineLoad` reads the
machine's busy time (``/proc/stat``: user, nice, system, irq, softirq) and the CPU time
of this process and all its descendants (``/proc/PID/stat``) at two marks, and reports, in
cores over the window:

* ``busy``: the whole machine;
* ``outside``: the machine less this benchmark's process tree (other work on the machine).
  The tree's CPU is, at each mark, the sum over this process and its descendants of their
  own and their waited-for children's CPU (``utime + stime + cutime + cstime``), so a
  process of the tree that starts or ends inside the window is counted as the tree's
  (once its parent has waited for it);
* ``steal``: time the hypervisor gave to other guests.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["LoadFigures", "MachineLoad", "process_table"]

_TICKS = os.sysconf("SC_CLK_TCK")


def _machine() -> tuple[float, float]:
    """(busy, steal) CPU seconds of the whole machine since boot, from /proc/stat.

    Busy: user, nice, system, irq, softirq (guest time is inside user); steal apart.
    """
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[:8])
    return (user + nice + system + irq + softirq) / _TICKS, steal / _TICKS


def read_stat(path: str | Path) -> tuple[str, list[str]] | None:
    """Return ``(comm, the fields after it)`` of a ``/proc/.../stat`` file, None when gone.

    After ``comm``, field 1 is the parent pid and fields 11-14 ``utime``, ``stime``,
    ``cutime``, ``cstime`` [clock ticks] (proc(5) fields 4, 14-17).
    """
    try:
        text = Path(path).read_text()
    except OSError:  # (gone meanwhile)
        return None
    return text[text.index("(") + 1:text.rindex(")")], text[text.rindex(")") + 2:].split()


def stat_cpu(fields: list[str], children: bool = False) -> float:
    """Return CPU seconds ``utime + stime`` of :func:`read_stat`'s fields.

    ``children``: plus ``cutime + cstime`` (the waited-for children's).
    """
    return sum(int(v) for v in fields[11:15 if children else 13]) / _TICKS


def process_table(children: bool = False) -> dict[int, tuple[int, float]]:
    """Every process now: pid -> (parent pid, CPU seconds), from /proc.

    CPU: ``utime + stime``; ``children``: plus ``cutime + cstime`` (its waited-for children's).
    """
    table: dict[int, tuple[int, float]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        stat = read_stat(entry / "stat")
        if stat is not None:
            table[int(entry.name)] = (int(stat[1][1]), stat_cpu(stat[1], children))
    return table


def _tree() -> dict[int, float]:
    """CPU seconds of this process and each descendant, with their waited-for children's."""
    table = process_table(children=True)
    members = {os.getpid()}
    grown = True
    while grown:
        grown = False
        for pid, (parent, _cpu) in table.items():
            if parent in members and pid not in members:
                members.add(pid)
                grown = True
    return {pid: table[pid][1] for pid in members if pid in table}


@dataclass(frozen=True)
class LoadFigures:
    """Machine load over a window [core] (module docstring)."""

    busy: float
    outside: float
    steal: float

    def line(self) -> str:
        """One line for people."""
        return (f"machine over the window: busy {self.busy:.3f} core, outside this "
                f"benchmark's processes {self.outside:.3f} core, steal {self.steal:.3f} core")


class MachineLoad:
    """Marks the machine's and the benchmark's CPU at :meth:`start` and :meth:`stop`."""

    def __init__(self) -> None:
        self._start: tuple[float, tuple[float, float], dict[int, float]] | None = None

    def start(self) -> None:
        """Take the first mark."""
        self._start = (time.monotonic(), _machine(), _tree())

    def stop(self) -> LoadFigures:
        """Take the second mark; return the figures over the window."""
        if self._start is None:
            raise RuntimeError("MachineLoad.stop before start")
        t1, (busy1, steal1), tree1 = time.monotonic(), _machine(), _tree()
        t0, (busy0, steal0), tree0 = self._start
        seconds = max(t1 - t0, 1e-9)
        own = sum(tree1.values()) - sum(tree0.values())
        return LoadFigures(busy=(busy1 - busy0) / seconds,
                           outside=max(0.0, busy1 - busy0 - own) / seconds,
                           steal=(steal1 - steal0) / seconds)
