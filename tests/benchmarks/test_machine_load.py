"""MachineLoad tells the benchmark's own CPU from other work on the machine (real processes).

No timing assertions: each check compares two readings of the same kernel counters
(``/proc``), so it holds however busy the machine is.
"""

import os
import resource
import signal
import subprocess
import sys
import time

from benchmarks.live_cpu import read_cpu
from benchmarks.machine_load import MachineLoad

BUSY = [sys.executable, "-c", "while True: pass"]
#: [core] /proc counts CPU time in clock ticks (1/100 s): two readings over ~1 s each
TICK_TOLERANCE = 3 / os.sysconf("SC_CLK_TCK")


def _orphan() -> int:
    """Start a busy loop that is not a descendant of this process (reparented); its pid."""
    out = subprocess.run(["bash", "-c", f"setsid {' '.join(BUSY[:2])} '{BUSY[2]}' "
                          "> /dev/null 2>&1 < /dev/null & echo $!"],
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


def test_children_count_as_the_benchmarks_own_and_an_orphan_as_outside():
    """A child running throughout and one that starts and ends inside the window: own."""
    child = subprocess.Popen(BUSY)
    orphan = _orphan()
    try:
        load = MachineLoad()
        time.sleep(0.2)  # both running
        c0, o0, t0 = read_cpu(child.pid), read_cpu(orphan), time.monotonic()
        load.start()
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, "-c", "import time\nend = time.process_time() + 0.3\n"
                        "while time.process_time() < end: pass"], check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)  # a child started and ended
        time.sleep(0.7)
        figures = load.stop()
        c1, o1, t1 = read_cpu(child.pid), read_cpu(orphan), time.monotonic()
    finally:
        child.kill()
        child.wait(10)
        os.kill(orphan, signal.SIGKILL)
    seconds = t1 - t0
    child_core, orphan_core = (c1 - c0) / seconds, (o1 - o0) / seconds
    assert child_core > 0.05 and orphan_core > 0.05  # both ran in the window
    short = (after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime) / seconds
    own = figures.busy - figures.outside
    assert own >= child_core + short - 2 * TICK_TOLERANCE, (figures, child_core, short)
    assert figures.outside >= orphan_core - TICK_TOLERANCE, (figures, orphan_core)
    assert 0.0 <= figures.steal <= figures.busy
    assert figures.busy <= os.cpu_count() + TICK_TOLERANCE
    assert "outside this benchmark's processes" in figures.line()
