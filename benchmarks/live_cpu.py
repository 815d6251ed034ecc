"""CPU budget of the live chain: CPU seconds per second of rig time, per node and per message.

``python -m benchmarks.live_cpu`` runs the full ``clutch demo --json --no-plots`` (``--quick``:
the short profile) and, in the same ROS domain, a bare rclpy echo node (the baseline:
``python -m benchmarks.estimator_node echo``, subscribing ``rig_state`` as the estimator does
and publishing one message per input, in a process of its own). It finds each node's process
(the demo's children, by their ``clutch_ros.nodes.<name>`` command line), reads
``utime + stime`` from ``/proc/PID/stat`` when the driven run starts (the demo's first
progress line) and when it ends (the line after it), and prints per node:

* ``cpu``: CPU seconds per second of rig time [core] (rig time: wall time of the window less
  the time the simulated rig reports lost, ``rig_lost_time_s``);
* ``per message``: CPU per message the node handles [ms]: ``rig_state`` for the bridge, the
  estimator, the echo node and the rig (its frames trigger them), ``pressure_command`` for the
  controller (counted from the demo's bag within the window);

and the chain's total (can_bridge + estimator + controller) against the budget, 0.25 core
(issue 23). ``--skeleton`` also runs, beside the demo and in its domain under the namespace
``/skeleton``, the chain's messages without its work (:mod:`benchmarks.chain_skeleton`: three
bare rclpy processes with the chain's topics, types, QoS, rates, mechanisms and scheduling
policy) and prints their CPU, and their CPU per message at the chain's own message rates as
the chain's floor in rclpy and DDS (under load their cycles may skip late ticks).
``--one-process`` runs the chain as one process (``clutch demo --one-process``, as ``clutch
up --one-process``): its row ``composed`` is the chain. ``--json`` prints the figures as
JSON. Figures depend on machine load: the last line says how much CPU other work on the
machine took over the window (:mod:`benchmarks.machine_load`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.chain_skeleton import published_between
from benchmarks.machine_load import (
    LoadFigures,
    MachineLoad,
    process_table,
    read_stat,
    stat_cpu,
)
from clutch_ros.cli.demo import RT_PRIORITY

__all__ = ["CHAIN", "NODES", "DemoRun", "main", "node_pids", "read_cpu"]

NODES = ("rig_sim", "can_bridge", "estimator", "controller")
CHAIN = ("can_bridge", "estimator", "controller")
#: ``--one-process``: the chain runs as one process (``clutch demo --one-process``)
ONE_PROCESS_NODES = ("rig_sim", "composed")
ECHO = "echo (baseline)"
#: ``--skeleton``: per skeleton node (benchmarks.chain_skeleton role), the chain's node it
#: stands for and the topic it publishes once per message it handles (its ``--report``)
SKELETON_OF = {"skeleton bridge": ("can_bridge", "rig_state"),
               "skeleton estimator": ("estimator", "clutch_estimate"),
               "skeleton controller": ("controller", "pressure_command")}
SKELETON = tuple(SKELETON_OF)
BUDGET = 0.25  # [core] can_bridge + estimator + controller, issue 23
#: topic whose messages each node handles (per-message figure)
PER_MESSAGE_TOPIC = {"can_bridge": "/rig_state", "estimator": "/rig_state",
                     "controller": "/pressure_command", ECHO: "/rig_state",
                     "rig_sim": "/rig_state", "composed": "/rig_state"}
#: the demo's progress line, ``[  0.0/48.0 s] request ...`` (not a node's ``[INFO] [...`` log)
_PROGRESS = re.compile(r"\[\s*[\d.]+/[\d.]+ s\]")


def read_cpu(pid: int) -> float | None:
    """Return ``utime + stime`` of process ``pid`` [s], or None when it is gone."""
    stat = read_stat(f"/proc/{pid}/stat")
    return None if stat is None else stat_cpu(stat[1])


def _children(pid: int) -> list[int]:
    return [child for child, (parent, _cpu) in process_table().items() if parent == pid]


def node_pids(parent: int) -> dict[str, int]:
    """Return ``{node name: pid}`` of the ``clutch_ros.nodes.<name>`` children of ``parent``."""
    found = {}
    for pid in _children(parent):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        for arg in argv:
            name = arg.decode(errors="replace")
            if name.startswith("clutch_ros.nodes."):
                found[name.rsplit(".", 1)[1]] = pid
    return found


def _count_messages(bag: Path, start_ns: int, end_ns: int) -> dict[str, int]:
    """Messages per topic of ``bag`` logged within [start_ns, end_ns] (wall clock) [1]."""
    from rosbags.highlevel import AnyReader

    counts: dict[str, int] = {}
    with AnyReader([bag]) as reader:
        for conn, _t, _ in reader.messages(start=start_ns, stop=end_ns):
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


class DemoRun:
    """The demo process, its stderr watched for the window's start and end."""

    def __init__(self, cmd: list[str], env: dict):
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.domain: str | None = None
        self.lines: list[str] = []
        self.started = threading.Event()
        self.ended = threading.Event()
        self.on_start = None  # callbacks run in the reader thread at the marks
        self.on_end = None
        self._err = threading.Thread(target=self._read_stderr, daemon=True)
        self._err.start()

    def join(self) -> None:
        """Wait until the demo's stderr is read to its end."""
        self._err.join(30.0)

    def _read_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))
            match = re.search(r"ROS domain (\d+)", line)
            if match and self.domain is None:
                self.domain = match.group(1)
            if _PROGRESS.match(line) and not self.started.is_set():
                if self.on_start:
                    self.on_start()
                self.started.set()
            elif self.started.is_set() and not line.strip() and not self.ended.is_set():
                if self.on_end:
                    self.on_end()
                self.ended.set()


def _skeleton_report(path: Path) -> dict | None:
    """Return a skeleton node's ``--report``, or None when it wrote none."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def measure(quick: bool, output: Path, demo_args: list[str], one_process: bool = False,
            skeleton: bool = False) -> dict:
    """Run the demo with the echo node beside it; return the figures (module docstring).

    ``one_process``: the demo's ``--one-process``; the chain is then the one process
    ``composed`` (its CPU is the chain's; per node it cannot be split). ``skeleton``: the
    chain's skeleton beside it too (:mod:`benchmarks.chain_skeleton`).
    """
    node_names = ONE_PROCESS_NODES if one_process else NODES
    chain_names = ("composed",) if one_process else CHAIN
    demo_args = [*demo_args, *(["--one-process"] if one_process else [])]
    cmd = [sys.executable, "-m", "clutch_ros.cli", "demo", "--json", "--no-plots",
           "-o", str(output), *(["--quick"] if quick else []), *demo_args]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    run = DemoRun(cmd, env)
    extra: list[subprocess.Popen] = []  # the echo node and the skeleton's
    side = Path(tempfile.mkdtemp(prefix="live_cpu-skeleton-"))  # the skeleton's reports
    marks: dict[str, tuple[float, int, dict[str, float | None]]] = {}
    pids: dict[str, int] = {}
    load = MachineLoad()
    machine = []

    def sample(mark: str) -> None:
        marks[mark] = (time.monotonic(), time.time_ns(),
                       {name: read_cpu(pid) for name, pid in pids.items()})
        if mark == "start":
            load.start()
        else:
            machine.append(load.stop())

    run.on_start = lambda: sample("start")
    run.on_end = lambda: sample("end")
    try:
        deadline = time.monotonic() + 90.0
        while run.domain is None or len(pids) < len(node_names):  # the demo starts its nodes
            if run.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the demo did not start its nodes:\n" + "\n".join(run.lines))
            if run.domain is not None:
                pids.update(node_pids(run.proc.pid))
            time.sleep(0.05)
        echo_env = dict(env, ROS_DOMAIN_ID=run.domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        extra.append(subprocess.Popen([sys.executable, "-m", "benchmarks.estimator_node",
                                       "echo"], env=echo_env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        pids[ECHO] = extra[-1].pid
        for name in SKELETON if skeleton else ():
            # the scheduling of the node it stands for (the demo runs its nodes at SCHED_FIFO
            # unless --no-realtime): at the normal policy the skeleton lost a third of its ticks
            rt = [] if "--no-realtime" in demo_args else [
                "-p", "rt.policy:=fifo", "-p", f"rt.priority:={RT_PRIORITY[SKELETON_OF[name][0]]}"]
            extra.append(subprocess.Popen(
                [sys.executable, "-m", "benchmarks.chain_skeleton", name.split()[1],
                 "--report", str(side / f"{name.replace(' ', '_')}.json"),
                 "--ros-args", "-r", "__ns:=/skeleton", *rt],
                env=echo_env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            pids[name] = extra[-1].pid
        assert run.proc.stdout is not None
        stdout = run.proc.stdout.read()  # (stderr is the reader thread's)
        run.proc.wait(600)
        run.join()
    finally:
        for proc in extra:
            proc.terminate()
        for proc in extra:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        if run.proc.poll() is None:
            run.proc.kill()
        reports = {name: _skeleton_report(side / f"{name.replace(' ', '_')}.json")
                   for name in (SKELETON if skeleton else ())}
        shutil.rmtree(side, ignore_errors=True)
    if run.proc.returncode != 0 or "start" not in marks or "end" not in marks:
        raise RuntimeError(f"the demo failed (exit {run.proc.returncode}):\n"
                           + "\n".join(run.lines[-20:]))
    summary = json.loads(stdout)
    (t0, w0, cpu0), (t1, w1, cpu1) = marks["start"], marks["end"]
    lost = float(summary.get("rig_lost_time_s", 0.0) or 0.0)
    lost = lost if math.isfinite(lost) else 0.0  # NaN: the rig did not report
    rig_time = (t1 - t0) - lost
    counts = _count_messages(Path(summary["bag"]), w0, w1)
    nodes = {}
    for name in (*node_names, ECHO, *(SKELETON if skeleton else ())):
        a, b = cpu0.get(name), cpu1.get(name)
        if a is None or b is None:
            raise RuntimeError(f"{name}: process gone before the end of the window")
        if name in SKELETON:  # its own count within the window (its sampled counts)
            topic = f"/skeleton/{SKELETON_OF[name][1]}"
            report = reports[name]
            if report is None:
                raise RuntimeError(f"{name}: it left no report of its messages")
            if report["ready"] > w0 * 1e-9:  # its start-up is no part of the floor
                raise RuntimeError(f"{name}: its node was ready {report['ready'] - w0 * 1e-9:.1f}"
                                   " s after the driven run had started")
            n = round(published_between(report, w0 * 1e-9, w1 * 1e-9)[SKELETON_OF[name][1]])
        else:
            topic = PER_MESSAGE_TOPIC[name]
            n = counts.get(topic, 0)
        nodes[name] = {"pid": pids[name], "cpu_s": b - a, "cpu_core": (b - a) / rig_time,
                       "messages": n, "topic": topic,
                       "cpu_per_message_ms": (b - a) / n * 1e3 if n else float("nan")}
    chain = sum(nodes[name]["cpu_core"] for name in chain_names)
    floor = sum(nodes[name]["cpu_core"] for name in SKELETON) if skeleton else None
    # the skeleton's CPU per message at the chain's own message rates (under load its cycles
    # skip late ticks; the per-message cost is what the chain's messages would cost)
    floor_at_rates = sum(nodes[skel]["cpu_per_message_ms"] * 1e-3 * nodes[real]["messages"]
                         / rig_time for skel, (real, _topic) in SKELETON_OF.items()
                         if real in nodes) if skeleton and not one_process else None
    return {"skeleton_core": floor, "skeleton_at_chain_rates_core": floor_at_rates,
            "rig_time_s": rig_time, "rig_lost_time_s": lost, "nodes": nodes,
            "chain_core": chain, "budget_core": BUDGET, "within_budget": chain <= BUDGET,
            "machine": {"busy_core": machine[0].busy, "outside_core": machine[0].outside,
                        "steal_core": machine[0].steal},
            "demo": {k: summary.get(k) for k in ("steady_state_error", "within_10pct",
                                                  "worst_overshoot", "realtime")}}


def main(argv=None) -> int:
    """Run the benchmark and print one row per node (or JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the demo's short profile")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--one-process", action="store_true",
                        help="bridge, estimator and controller in one process (clutch demo "
                             "--one-process); the chain row is that process")
    parser.add_argument("--skeleton", action="store_true",
                        help="also run the chain's messages without its work beside the demo "
                             "(benchmarks.chain_skeleton) and print their CPU: the floor")
    parser.add_argument("--keep", help="run directory to keep (default: a temporary one)")
    parser.add_argument("--demo-arg", action="append", default=[],
                        help="extra argument for clutch demo (repeatable)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="live_cpu-") as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "demo"
        res = measure(args.quick, out, args.demo_arg, args.one_process, args.skeleton)
    if args.json:
        print(json.dumps(res, indent=2, sort_keys=True))
        return 0
    print(f"rig time {res['rig_time_s']:.1f} s (lost {res['rig_lost_time_s']:.2f} s)")
    print(f"{'node':18s} {'cpu [core]':>10s} {'per message [ms]':>17s}  messages")
    for name, r in res["nodes"].items():
        print(f"{name:18s} {r['cpu_core']:10.3f} {r['cpu_per_message_ms']:17.3f}  "
              f"{r['messages']} {r['topic']}")
    print(f"chain (bridge + estimator + controller): {res['chain_core']:.3f} core "
          f"(budget {BUDGET} core: {'met' if res['within_budget'] else 'NOT met'})")
    if res["skeleton_core"] is not None:
        print(f"skeleton (the chain's messages in bare rclpy, no work): "
              f"{res['skeleton_core']:.3f} core")
    floor = res["skeleton_at_chain_rates_core"]
    if floor is not None:
        print(f"skeleton at the chain's message rates: {floor:.3f} core (the floor); the "
              f"chain's own work: {res['chain_core'] - floor:.3f} core")
    m = res["machine"]
    print(LoadFigures(m["busy_core"], m["outside_core"], m["steal_core"]).line())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
