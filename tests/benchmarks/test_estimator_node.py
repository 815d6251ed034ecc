"""The estimator benchmark's --realtime option: validated, and applied to its own processes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from benchmarks import estimator_node

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.parametrize("priority", ["-1", "100"])
def test_a_priority_outside_1_to_99_is_refused_before_anything_runs(priority, capsys):
    with pytest.raises(SystemExit) as exc:
        estimator_node.main(["--realtime", priority])
    assert exc.value.code == 2
    assert "--realtime: a priority 1..99 (or 0 for off)" in capsys.readouterr().err


def test_realtime_zero_leaves_the_policy_alone():
    assert estimator_node.realtime(0) == "normal policy"


def test_realtime_sets_fifo_on_the_process_or_says_why_not():
    # in a child process: SCHED_FIFO on the pytest process would outlive the test
    code = ("import os; from benchmarks.estimator_node import realtime; m = realtime(7); "
            "print(m); print(os.sched_getscheduler(0) == os.SCHED_FIFO, "
            "os.sched_getparam(0).sched_priority)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=60, check=True).stdout.splitlines()
    assert "SCHED_FIFO priority 7" in out[0]  # applied, or refused with its reason
    refused = "SCHED_FIFO priority 7:" in out[0]  # (refusals are "option: reason")
    assert out[1] == ("False 0" if refused else "True 7")
