"""Where a live node's CPU goes: thread CPU per call of its hot functions during the full demo.

``python -m benchmarks.live_profile NODE [TARGET ...]`` runs ``clutch demo --json --no-plots``
(``--quick``: the short profile) with :mod:`benchmarks.profile_hook` in the node's process, and
over the demo's driven part (the window of ``python -m benchmarks.live_cpu``) prints per target
(``module:Class.method`` or ``module:function``; default: :data:`DEFAULT_TARGETS` of the node)
its calls per second, the thread CPU per call [µs] and its share of a core, then the CPU of
each thread of the process [core] and of the whole process. The figures are the threads' own
CPU clocks (user + system, as ``/proc`` counts), exact rather than sampled: see the hook's
docstring for why a sampling profiler was not enough, and for what is counted (inclusive
figures, ~1 µs of the wrapper per call).

Mechanism: a ``sitecustomize.py`` in a temporary directory put first on ``PYTHONPATH`` of the
demo and its nodes (none exists in the project's virtual environment to be shadowed); the
window is signalled by two files in that directory. Figures depend on machine load: the last
line says how much CPU other work took over the window (:mod:`benchmarks.machine_load`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.live_cpu import DemoRun
from benchmarks.machine_load import LoadFigures, MachineLoad
from benchmarks.profile_hook import ENV, parse_target

__all__ = ["DEFAULT_TARGETS", "main", "measure"]

#: the hot paths found on the live demo (issue 23), per node
DEFAULT_TARGETS = {
    "can_bridge": (
        "clutch_ros.canbus.bus:ReconnectingBus.recv_batch",
        "clutch_ros.canbus.bus:ReconnectingBus.recv_columns",
        "clutch_ros.canbus.udp_columns:drop_echoes",
        "clutch_ros.nodes.can_bridge_receive:ReceiveSide._on_frames",
        "clutch_ros.canbus.assembler:RigStateAssembler.feed_frame",
        "clutch_ros.canbus.intake:CompiledIntake.run",
        "clutch_ros.nodes.can_bridge_receive:ReceiveSide._publish",
        "clutch_ros.canbus.assembler:RigStateAssembler.snapshot",
        "clutch_ros.nodes.can_bridge_send:PumpSender.cycle",
        "clutch_ros.nodes.can_bridge_send:PumpSender.on_command",
        "clutch_ros.canbus.bus:ReconnectingBus.send",
    ),
    "estimator": (
        "clutch_ros.nodes.estimator:EstimatorNode._estimate",
        "clutch_ros.model.adaptation:AdaptiveEstimator.update",
        "clutch_ros.model.pack:PackModel.step",
        "clutch_ros.model.uncertainty:TorqueStd.update",
        "clutch_ros.nodes.loss_tracker:LossTracker.received",
    ),
    "controller": (
        "clutch_ros.nodes.controller:ControllerNode._poll",
        "clutch_ros.nodes.controller:ControllerNode._step",
        "clutch_ros.nodes.polled:PolledSubscription.take",
        "clutch_ros.model.control:TorqueController.update",
    ),
}
_SITE = "from benchmarks.profile_hook import install\n\ninstall()\n"
RESULT_WAIT = 10.0  # [s] for the node's result file after the demo has ended


def measure(node: str, targets: list[str], quick: bool, demo_args: list[str],
            control: Path) -> dict:
    """Run the demo with ``node`` hooked; return the node's figures (module docstring)."""
    for target in targets:
        parse_target(target)  # a typo fails here, not silently in the node
    (control / "sitecustomize.py").write_text(_SITE)
    root = Path(__file__).resolve().parents[1]
    path = os.pathsep.join(p for p in (str(control), str(root),
                                       os.environ.get("PYTHONPATH", "")) if p)
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=path,
               **{ENV: json.dumps({"node": node, "targets": targets,
                                   "control": str(control)})})
    cmd = [sys.executable, "-m", "clutch_ros.cli", "demo", "--json", "--no-plots",
           "-o", str(control / "demo"), *(["--quick"] if quick else []), *demo_args]
    run = DemoRun(cmd, env)
    load = MachineLoad()
    figures: list[LoadFigures] = []

    def start() -> None:
        load.start()
        (control / "start").touch()

    def end() -> None:
        (control / "stop").touch()
        figures.append(load.stop())

    run.on_start, run.on_end = start, end
    try:
        assert run.proc.stdout is not None
        run.proc.stdout.read()
        run.proc.wait(600)
        run.join()
    finally:
        if run.proc.poll() is None:
            run.proc.kill()
    if run.proc.returncode != 0 or not figures:
        raise RuntimeError(f"the demo failed (exit {run.proc.returncode}):\n"
                           + "\n".join(run.lines[-20:]))
    deadline = time.monotonic() + RESULT_WAIT
    while not (found := sorted(control.glob(f"{node}-*.json"))):
        if time.monotonic() > deadline:
            raise RuntimeError(f"no process of node {node!r} reported: is it one of the "
                               "demo's nodes (clutch_ros.nodes.<node>)?")
        time.sleep(0.1)
    res = json.loads(found[0].read_text())
    m = figures[0]
    res["node"], res["machine"] = node, {"busy": m.busy, "outside": m.outside,
                                         "steal": m.steal}
    return res


def _print(res: dict) -> None:
    window = res["window_s"]
    print(f"{res['node']} (pid {res['pid']}), window {window:.1f} s")
    print(f"{'target':64s} {'calls/s':>8s} {'us/call':>8s} {'core':>6s}")
    rows = sorted(res["targets"].items(), key=lambda kv: -kv[1]["cpu_s"])
    for target, t in rows:
        per_call = t["cpu_s"] / t["calls"] * 1e6 if t["calls"] else float("nan")
        print(f"{target:64s} {t['calls'] / window:8.1f} {per_call:8.1f} "
              f"{t['cpu_s'] / window:6.3f}")
    for target, why in res["errors"].items():
        print(f"{target:64s} not found: {why}")
    print("threads [core]: " + ", ".join(
        f"{name} {cpu / window:.3f}" for name, cpu in sorted(
            res["threads_cpu_s"].items(), key=lambda kv: -kv[1]) if cpu > 0.0))
    print(f"process: {res['process_cpu_s'] / window:.3f} core")
    m = res["machine"]
    print(LoadFigures(m["busy"], m["outside"], m["steal"]).line())


def main(argv=None) -> int:
    """Run the benchmark and print the node's figures (or JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("node", help="the node to profile: can_bridge, estimator, controller, "
                                     "rig_sim (clutch_ros.nodes.<node>)")
    parser.add_argument("targets", nargs="*",
                        help="module:Class.method or module:function (default: the node's "
                             "hot paths, DEFAULT_TARGETS)")
    parser.add_argument("--quick", action="store_true", help="the demo's short profile")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--demo-arg", action="append", default=[],
                        help="extra argument for clutch demo (repeatable)")
    args = parser.parse_args(argv)
    targets = args.targets or list(DEFAULT_TARGETS.get(args.node, ()))
    try:
        for target in targets:
            parse_target(target)
    except ValueError as err:
        parser.error(str(err))
    with tempfile.TemporaryDirectory(prefix="live_profile-") as tmp:
        res = measure(args.node, targets, args.quick, args.demo_arg, Path(tmp))
    if args.json:
        print(json.dumps(res, indent=2, sort_keys=True))
    else:
        _print(res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
