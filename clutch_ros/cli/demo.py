"""``clutch demo``: the simulated rig end to end, recorded, summarised and plotted.

Starts ``rig_sim``, ``can_bridge``, ``estimator`` and ``controller`` as separate processes
talking CAN over python-can's ``udp_multicast`` bus and ROS 2 over DDS (a private domain and
multicast group per run), drives the controller with a torque-request profile (steps and
ramps up to the estimator preset's rated torque at 10 and 30 rpm), records every topic to an
MCAP bag with rosbags, shuts everything down cleanly and prints a summary: fraction of the
settled time within ±10 % of the request, worst overshoot, estimator and reference-model RMSE
against the rig's measured torque. PNG plots are written next to the bag.

Every process of the run asks for real-time scheduling (SCHED_FIFO: the rig above the bridge
above the estimator, controller and this process's request driver and recorder), so other work
on the PC cannot starve the live chain; where the OS refuses (not root, no rtprio limit) the
run goes on at the normal policy and the summary says so (``realtime``). ``--no-realtime``
asks for nothing.

``--lockstep``: the simulated rig does not keep real time; it publishes ``/clock``, every node
of the chain (and this process's driver and recorder) runs with ``use_sim_time``, and the
rig waits for the chain to answer every 10 ms tick before it steps on
(:mod:`clutch_ros.nodes.lockstep`). The run then takes as long as the chain needs, and its
figures are the same on an idle and on a busy machine: the tests assert the targets on it.
It asks for no real-time scheduling (it needs none). The summary adds ``lockstep_timeouts``
(waits for the chain that expired; 0 in a good run) and ``wall_time_s``.

The rig's truth plant (``rig_truth`` preset, ``coulomb`` spline law) differs on purpose from
the estimator's preset, so the demo never compares a model with itself.

By default the estimator adapts its friction scale online from the rig's measured torque and
the controller inverts the adapted model with an integral trim on the measured torque
(README "Adaptive estimation"); ``--no-adapt`` runs the feed-forward path (fixed model, no
trim). The summary adds ``steady_state_error``: over every request plateau at least 1 s long
and at least 10 % of the rated torque, |mean measured torque over its last 0.5 s ÷ request −
1|, the largest (:mod:`clutch_ros.offline.steady_state`).
"""

from __future__ import annotations

import math
import os
import random
import sys
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.logging import LoggingSeverity

from clutch_ros.bag.reader import BagReader
from clutch_ros.cli.dispatch import emit_json
from clutch_ros.cli.processes import NodeProcess, isolated_ros_env, ros_param_args
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.errors import ClutchError
from clutch_ros.interfaces import DIAGNOSTICS
from clutch_ros.model import reference_torque
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.nodes.demo_driver import DemoDriver
from clutch_ros.nodes.lockstep import EPOCH_NS
from clutch_ros.nodes.realtime import RealtimeSettings, apply_realtime, policy_of, time_sharing
from clutch_ros.nodes.recorder import RecorderNode
from clutch_ros.offline.demo_summary import closed_loop_summary
from clutch_ros.offline.plots import plot_demo
from clutch_ros.rig.request_profile import demo_profile

__all__ = ["PUMP_RISE", "add_parser", "run"]

#: Pressure rise limit of the demo's controller and pump gate [Pa/s]: 75 bar/s. The pump
#: ECU kicks when its 20 ms-smoothed request rises faster than 100 bar/s; a 90 bar/s ramp
#: sent as a 10 ms staircase crosses that in its ripple (the rig's pump model: a 1.25 bar kick
#: on a clean staircase, 1.78 bar with 0-15 ms of arrival jitter; 75 bar/s: none, 0.68 bar).
#: The figures of both rates: benchmarks/RESULTS.md.
PUMP_RISE = 75e5

#: ``bridge.rate`` [Hz] in lock-step: a cap above the rig's one trigger frame per 10 ms tick.
LOCKSTEP_BRIDGE_RATE = 200.0
#: [s] wall: lock-step's bound of one wait of the rig for the chain (``rig.lockstep_timeout``).
#: Only a stuck chain should reach it: on a busy 2-core machine an answer took up to 1.7 s
#: (``lockstep_wait_max_s``), and an expired wait makes the run differ from an idle one
LOCKSTEP_TIMEOUT = 30.0
#: [s] lock-step: the profile starts at this simulation time (the rig's /clock from
#: ``nodes.lockstep.EPOCH_NS``), whenever the chain came up before it: every run the same
LOCKSTEP_START = 3.0

#: SCHED_FIFO priorities of the run's processes (1..99, higher preempts lower): the world
#: first, then the bridge (CAN frames queue in its socket), then the model and the driver.
#: the process name of can_bridge + estimator + controller with ``--one-process``
CHAIN = "chain"
RT_PRIORITY = {"rig_sim": 40, "can_bridge": 35, "estimator": 30, "controller": 30, "cli": 30}


def add_parser(sub) -> None:
    """Register ``clutch demo``."""
    p = sub.add_parser("demo", help="run the simulated rig end to end (the main job)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", help="run directory to create (default: "
                   "runs/demo-YYYYmmdd-HHMMSS); the bag is <output>/bag")
    p.add_argument("--params", default="flexiforce_8",
                   help="estimator/controller parameter preset or YAML file "
                        "(default: flexiforce_8)")
    p.add_argument("--rig-params", default="rig_truth",
                   help="truth-plant parameter preset or YAML file (default: rig_truth)")
    p.add_argument("--quick", action="store_true", help="shorter profile (about 25 s)")
    p.add_argument("--no-adapt", action="store_true",
                   help="feed-forward path: no online adaptation in the estimator, no torque "
                        "trim in the controller")
    p.add_argument("--rate", type=float, default=100.0,
                   help="RigState publishing rate of the bridge [Hz] (default 100)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="storage plugin of the bags written (default: mcap)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--dashboard", action="store_true",
                   help="also run the dashboard node: watch the run live in Foxglove at "
                        "ws://127.0.0.1:PORT (README.md)")
    p.add_argument("--dashboard-port", type=int, default=8765,
                   help="port of --dashboard (default 8765)")
    p.add_argument("--no-realtime", action="store_true",
                   help="run every process at the normal time-sharing policy (default: "
                        "SCHED_FIFO where the OS allows it, so other work cannot starve the "
                        "live chain)")
    p.add_argument("--lockstep", action="store_true",
                   help="the rig publishes /clock and waits for the chain (use_sim_time) every "
                        "10 ms tick instead of keeping real time: the same figures however "
                        "busy the machine is (implies --no-realtime; rig_state at 100 Hz, "
                        "--rate does not apply)")
    p.add_argument("--trigger", choices=("timer", "estimate"),
                   help="controller.trigger: 'timer' (a step every 10 ms) or 'estimate' (one "
                        "step per estimate); default: estimate with --lockstep, else timer")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--one-process", action="store_true",
                   help="can_bridge, estimator and controller in one process (process "
                        "'chain', as clutch up --one-process)")
    p.set_defaults(func=run)


def _say(text: str, end: str = "\n") -> None:
    sys.stderr.write(text + end)
    sys.stderr.flush()


def run(args) -> int:
    """Run the demo; return 0 (summary printed) or raise ClutchError."""
    if not 1.0 <= args.rate <= 2000.0:
        raise ClutchError(f"--rate must be within 1..2000 Hz, got {args.rate}")
    if not 0 <= args.dashboard_port <= 65535:
        raise ClutchError(f"--dashboard-port {args.dashboard_port} is not a TCP port")
    est_file = preset_path(args.params)
    rig_file = preset_path(args.rig_params)
    params = load_params(est_file)
    load_params(rig_file)  # fail early with a clear message
    out = Path(args.output or f"runs/demo-{time.strftime('%Y%m%d-%H%M%S')}")
    if out.exists():
        raise ClutchError(f"output {out} exists already; choose another with -o")
    out.mkdir(parents=True)
    rated = _rated_torque(params)
    profile = demo_profile(rated, quick=args.quick)
    domain = random.randint(150, 230)
    group = f"239.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(1, 254)}"
    can = {"can.interface": "udp_multicast", "can.channel": group}
    env = isolated_ros_env(domain)
    os.environ.update({"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    _say(f"clutch demo: run directory {out}, ROS domain {domain}, CAN udp_multicast {group}; "
         f"rated torque {rated:.0f} N m")
    specs = {
        "rig_sim": ros_param_args({**can, "rig.params_file": str(rig_file),
                                   "rig.slip_speed": profile[0].slip_speed}),
        # The pump request rises no faster than PUMP_RISE however DDS bunches the commands:
        # faster rises trigger the pump's pressure kick (thesis 5.1.1).
        "can_bridge": ros_param_args({**can, "bridge.rate": args.rate,
                                      "pump.rise_rate_limit": PUMP_RISE}),
        "estimator": ["--params-file", str(est_file),
                      *ros_param_args({"adapt.enabled": not args.no_adapt})],
        "controller": ["--params-file", str(est_file), *ros_param_args(
            {"controller.use_adapted_model": not args.no_adapt,
             "controller.rise_rate_limit": PUMP_RISE,
             "controller.trim_rate": 0.0 if args.no_adapt else ControllerSettings.trim_rate})],
    }
    if args.lockstep:
        args.no_realtime = True  # lock-step needs no priority: the rig waits for the chain
        specs["rig_sim"] += ros_param_args({"rig.lockstep": True, "rig.lockstep_request": True,
                                            "rig.lockstep_timeout": LOCKSTEP_TIMEOUT})
        # one RigSpeed per 10 ms tick: rig_state at 100 Hz. The cap sits above it, since on
        # stamps exactly 10 ms apart a 100 Hz token bucket refuses now and then by rounding
        # (the frame then waits for the bridge's flush timer, i.e. for the next /clock)
        specs["can_bridge"] += ros_param_args({"bridge.rate": LOCKSTEP_BRIDGE_RATE})
        # one step per estimate, the command stamped with it: the rig waits for it
        args.trigger = args.trigger or "estimate"
        for name in specs:
            if name != "rig_sim":
                specs[name] += ros_param_args({"use_sim_time": True})
    specs["controller"] += ros_param_args({"controller.trigger": args.trigger or "timer"})
    if not args.no_realtime:
        for name in specs:
            specs[name] += ros_param_args({"rt.policy": "fifo", "rt.priority": RT_PRIORITY[name]})
    if args.dashboard:
        specs["dashboard"] = ros_param_args({"dashboard.port": args.dashboard_port,
                                             "use_sim_time": bool(args.lockstep)})
        _say(f"clutch demo: dashboard at ws://127.0.0.1:{args.dashboard_port} (Foxglove: open "
             "connection -> Foxglove WebSocket; layout params/clutch_dashboard.json)")
    procs = []
    wall_start = time.monotonic()
    if getattr(args, "one_process", False):
        specs = _one_process(specs)
    try:
        for name, node_args in specs.items():
            # The simulated rig stands in for hardware that keeps real time whatever the PC
            # does: it alone gets a session, so a CPU share, of its own (NodeProcess); the
            # nodes under test share this process's. On a 2-core machine with each node in a
            # session of its own, five equal shares of ~40 % left the rig (~40 % of a core at
            # 1 kHz) short, and it dropped 3-10 s of a 30 s run: a slowed world.
            cmd = node_args if name == CHAIN else ["--ros-args", *node_args]
            procs.append(NodeProcess(name, cmd, env, out / "logs", own_session=name == "rig_sim",
                                     executable="composed" if name == CHAIN else None))
        if not args.no_realtime:  # this process's driver and recorder (DDS threads inherit)
            report = apply_realtime(RealtimeSettings("fifo", RT_PRIORITY["cli"]))
            if report.refused:
                _say(f"clutch demo: warning: {report.message()}; the run goes on at the "
                     "normal policy")
        written, driver = _drive(profile, procs, out, args)
        policies = {"cli": policy_of(os.getpid()),
                    **{proc.name: policy_of(proc.pid) for proc in procs}}
    finally:
        time_sharing()  # the summary and plots need no priority
        # lock-step: the rig (the clock) first, so the others' time stands still as they stop
        first = [p for p in procs if p.name == "rig_sim"] if args.lockstep else []
        for proc in first + [p for p in reversed(procs) if p not in first]:
            proc.stop()
    wall_time = time.monotonic() - wall_start
    summary = _summarise(out, profile, driver, written, rated, args)
    summary["lockstep"] = bool(args.lockstep)
    summary["wall_time_s"] = wall_time
    if args.lockstep:
        summary["lockstep_timeouts"] = rig_diagnostic(out / "bag", "lockstep_timeouts")
        summary["lockstep_wait_max_s"] = rig_diagnostic(out / "bag", "lockstep_wait_max_s")
        summary["lockstep_last_timeout"] = rig_diagnostic(out / "bag", "lockstep_last_timeout",
                                                          text=True)
    # True when every process of the chain ran at SCHED_FIFO (policy per process alongside)
    summary["realtime"] = all(policies.get(name, policies.get(CHAIN)) == "fifo"
                              for name in RT_PRIORITY)
    summary["scheduling"] = policies
    if args.dashboard:
        summary["dashboard"] = f"ws://127.0.0.1:{args.dashboard_port}"
    if args.json:

        emit_json(summary)
    else:
        _print_summary(summary)
    return 0


def _one_process(specs: dict[str, list[str]]) -> dict[str, list[str]]:
    """``--one-process``: the chain's node arguments as one ``composed`` command line."""
    from clutch_ros.nodes.composed import composed_args

    members = [(n, ["--ros-args", *specs.pop(n)]) for n in ("can_bridge", "estimator",
                                                            "controller")]
    return {**specs, CHAIN: composed_args(members)}


def _rated_torque(params) -> float:

    return float(abs(reference_torque(params, 40e5, 35.0, 10.0 * 2.0 * math.pi / 60.0)))


def _drive(profile, procs, out: Path, args):


    rclpy.init(args=[])
    executor = SingleThreadedExecutor()
    driver = DemoDriver(profile, on_clock=bool(args.lockstep))
    sim_time = rclpy.parameter.Parameter("use_sim_time", value=bool(args.lockstep))
    driver.set_parameters([sim_time])  # lock-step: profile time is the rig's /clock
    recorder = RecorderNode(parameter_overrides=[
        rclpy.parameter.Parameter("recorder.output", value=str(out / "bag")),
        rclpy.parameter.Parameter("recorder.storage", value=args.storage), sim_time])

    recorder.get_logger().set_level(LoggingSeverity.WARN)  # the summary says where the bag is
    executor.add_node(driver)
    executor.add_node(recorder)
    try:
        _say("waiting for the rig, bridge, estimator and controller ...")
        # lock-step: nothing depends on how long the start takes, on a busy machine minutes
        up_within = 300.0 if args.lockstep else 60.0
        deadline = time.monotonic() + up_within
        while min(driver.counts["rig"], driver.counts["estimate"], driver.counts["command"]) < 5:
            executor.spin_once(timeout_sec=0.05)
            _check_alive(procs)
            if time.monotonic() > deadline:
                raise ClutchError(f"the nodes did not come up within {up_within:g} s: "
                                  f"{driver.counts}; logs in {out / 'logs'}")
        start = EPOCH_NS * 1e-9 + LOCKSTEP_START
        if args.lockstep and driver.now() < start:  # a fixed simulation time: every run alike
            while driver.now() < start - 1e-6:
                executor.spin_once(timeout_sec=0.01)
                _check_alive(procs)
            driver.started_at = start
        else:
            if args.lockstep:
                _say(f"clutch demo: warning: the chain came up after {LOCKSTEP_START} s of "
                     "simulation time; the profile starts now (runs may differ)")
            driver.start()
        next_line = 0.0
        while not driver.finished:
            executor.spin_once(timeout_sec=0.01)
            _check_alive(procs)
            if driver.elapsed() >= next_line:
                _say(driver.progress_line(), end="\r" if sys.stderr.isatty() else "\n")
                next_line += 1.0
        # requests at 0 for a second (of the driver's clock: the rig's in lock-step), so the
        # pump releases; a wall-clock bound in case a lock-step rig stopped answering
        end, wall_end = driver.elapsed() + 1.0, time.monotonic() + 30.0
        while driver.elapsed() < end and time.monotonic() < wall_end:
            executor.spin_once(timeout_sec=0.01)
            _check_alive(procs)
        _say("")
    finally:
        recorder.drain(executor, quiet=0.3, limit=3.0)  # what DDS still queues: into the bag
        executor.shutdown()
        written = recorder.close()
        recorder.destroy_node()
        driver.destroy_node()
        rclpy.try_shutdown()
    return written, driver


def rig_diagnostic(bag: Path, key: str, node: str = "/rig_sim",
                   text: bool = False) -> float | str:
    """Return the last value of ``key`` in ``node``'s /diagnostics in ``bag`` (NaN: none).

    ``text``: the value as it is (a str; "" when none), not as a float.
    """
    value: float | str = "" if text else math.nan
    with BagReader(bag) as reader:
        if DIAGNOSTICS.absolute not in reader.topics:
            return value
        for _, _, msg in reader.messages([DIAGNOSTICS.absolute]):
            for status in msg.status:
                for kv in status.values if status.name == node else ():
                    if kv.key == key:
                        value = kv.value if text else float(kv.value)
    return value


def _check_alive(procs) -> None:
    for proc in procs:
        if not proc.alive():
            raise ClutchError(f"node {proc.name} exited unexpectedly; last log lines:\n"
                              f"{proc.tail()}")


def _summarise(out: Path, profile, driver, written, rated, args) -> dict:

    summary = closed_loop_summary(out / "bag", profile, driver.started_at, rated)
    summary.update({"bag": str(out / "bag"), "rated_torque_nm": rated, "messages": written,
                    "adaptive": not args.no_adapt})
    if not args.no_plots:
        summary["plots"] = [str(p) for p in plot_demo(out / "bag", profile, driver.started_at,
                                                      out)]
    return summary


def _print_summary(s: dict) -> None:
    lines = [
        "clutch demo summary",
        f"  within ±10 % of request (settled):  {100 * s['within_10pct']:.1f} % of time",
        f"  worst overshoot (measured/request): {s['worst_overshoot']:.3f}"
        f" at {s['worst_overshoot_time_s']:.2f} s (longest > 1.1: "
        f"{s['longest_overshoot_s']:.2f} s)",
        f"  estimator RMSE vs measured torque:  {s['estimator_rmse_nm']:.1f} N m"
        f" ({100 * s['estimate_coverage']:.1f} % of rig samples estimated)",
        f"  reference (Eq. 1) RMSE:             {s['reference_rmse_nm']:.1f} N m",
        f"  steady-state error (plateaus):      {100 * s['steady_state_error']:.2f} %"
        f" (worst of {s['plateaus']} plateaus, last 0.5 s mean vs request)",
        "  adaptation:                         " + (
            f"friction scale {s['friction_scale']:.4f} +- {s['friction_scale_std']:.4f}, "
            f"largest trim {s['max_trim_pa'] / 1e5:.2f} bar" if s["adaptive"]
            else "off (--no-adapt: feed-forward path)"),
        f"  bag: {s['bag']}",
    ]
    if s["lockstep"]:
        lines.insert(-1, f"  lock-step: {s['wall_time_s']:.0f} s of wall time, "
                     f"{s['lockstep_timeouts']:.0f} waits for the chain expired")
    if s.get("rig_lost_time_s", 0.0) > 0.0:  # NaN (no report) compares False
        lines.insert(-1, f"  warning: the simulated rig fell behind real time and dropped "
                     f"{s['rig_lost_time_s']:.2f} s (the machine is short of CPU; the "
                     "figures above are of a slowed world)")
    lines += [f"  plot: {p}" for p in s.get("plots", [])]
    sys.stdout.write("\n".join(lines) + "\n")
