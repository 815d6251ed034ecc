"""The live profile hook counts thread CPU per call in a real child process, exactly."""

import json
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from benchmarks import profile_hook as hook

BURN_S = 0.002  # [s] of its thread's CPU each burn() call uses (a busy loop on that clock)

_WORKER = '''
import time


class Worker:
    def burn(self):
        """Use BURN_S of this thread's CPU (busy loop on the thread's own clock)."""
        end = time.thread_time() + {burn}
        while time.thread_time() < end:
            pass

    def outer(self):
        self.burn()


def idle():
    time.sleep(0.001)
'''
_MAIN = '''
import sys
import threading
import time
from pathlib import Path

import worker


class Local:
    def spin(self):
        worker.Worker().outer()


local = Local()
done = Path(sys.argv[1]) / "exit"
def loop():
    while not done.exists():
        local.spin()
        worker.idle()


threading.Thread(target=loop, name="burner").start()
'''


def _run_child(tmp_path: Path, targets: list[str]) -> dict:
    (tmp_path / "worker.py").write_text(textwrap.dedent(_WORKER.format(burn=BURN_S)))
    (tmp_path / "main.py").write_text(textwrap.dedent(_MAIN))
    (tmp_path / "sitecustomize.py").write_text(
        "from benchmarks.profile_hook import install\n\ninstall()\n")
    root = Path(__file__).resolve().parents[2]
    env = {"PYTHONPATH": f"{tmp_path}:{root}", "PATH": "/usr/bin:/bin",
           hook.ENV: json.dumps({"node": "fake", "targets": targets,
                                 "control": str(tmp_path)})}
    # the extra argument stands for the node's module on a node's command line
    proc = subprocess.Popen([sys.executable, str(tmp_path / "main.py"), str(tmp_path),
                             "clutch_ros.nodes.fake"], env=env)
    try:
        time.sleep(1.0)  # started, the imports done
        (tmp_path / "start").touch()
        time.sleep(1.5)
        (tmp_path / "stop").touch()
        deadline = time.monotonic() + 10.0
        while not (found := list(tmp_path.glob("fake-*.json"))):
            assert time.monotonic() < deadline, "the hooked child wrote no result"
            time.sleep(0.05)
    finally:
        (tmp_path / "exit").touch()
        proc.wait(10)
    return json.loads(found[0].read_text())


def test_counts_each_calls_thread_cpu_in_imported_and_main_modules(tmp_path):
    res = _run_child(tmp_path, ["worker:Worker.burn", "worker:Worker.outer", "worker:idle",
                                "__main__:Local.spin", "worker:Missing.burn"])
    calls = res["targets"]
    burn = calls["worker:Worker.burn"]
    assert burn["calls"] > 50  # ~1.5 s of 2 ms calls (fewer on a loaded machine)
    # each call's own CPU: the busy loop ends on the first reading past BURN_S; the wrapper
    # and the loop's last iteration add microseconds, a preemption inside adds none (CPU clock)
    assert BURN_S <= burn["cpu_s"] / burn["calls"] <= BURN_S + 0.0005
    # inclusive figures: the outer calls contain the inner ones, also the main module's
    # (wrapped when the window opens; local.spin is looked up on the class at each call)
    for outer in ("worker:Worker.outer", "__main__:Local.spin"):
        assert abs(calls[outer]["calls"] - burn["calls"]) <= 1, (outer, calls)
        assert calls[outer]["cpu_s"] >= burn["cpu_s"] * 0.99, (outer, calls)
    # sleeping uses no CPU: the idle calls count, their CPU stays small
    assert calls["worker:idle"]["calls"] >= burn["calls"] - 1
    assert calls["worker:idle"]["cpu_s"] / calls["worker:idle"]["calls"] < 0.0005
    assert "worker:Missing.burn" in res["errors"]  # reported, not raised in the node
    # the thread's CPU over the window (/proc) holds what was counted in it
    threads = res["threads_cpu_s"]
    assert threads["burner"] >= burn["cpu_s"] - 0.02  # /proc counts in 10 ms ticks
    assert res["process_cpu_s"] >= threads["burner"] - 0.02
    assert 1.3 <= res["window_s"] <= 2.5  # start to stop, seen within POLL each


def test_only_the_named_nodes_process_is_hooked(monkeypatch, tmp_path):
    monkeypatch.setenv(hook.ENV, json.dumps({"node": "no_such_node", "targets": [],
                                             "control": str(tmp_path)}))
    assert hook.install() is False  # this process is no clutch_ros.nodes.no_such_node
    monkeypatch.delenv(hook.ENV)
    assert hook.install() is False


@pytest.mark.parametrize("bad", ["worker", "worker:", ":f", "worker:A.b.c", "worker:1x"])
def test_a_malformed_target_is_refused_with_its_text(bad):
    with pytest.raises(ValueError, match="expected module:Class.method"):
        hook.parse_target(bad)
    assert hook.parse_target("a.b:C.d") == ("a.b", "C.d")
