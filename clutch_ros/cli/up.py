"""``clutch up LAUNCHFILE [name:=value ...]``: start the node set of an XML launch file here.

``ros2 launch`` is not installed where ROS 2 comes from the package index, so this reads the
same XML launch files (what :mod:`clutch_ros.config.launch_file` accepts: the launch_xml
elements rig files use, with ros2 launch's meaning) and starts each ``<node>`` as its own
process with the demo's supervision (:class:`clutch_ros.cli.processes.NodeProcess`): output
to ``<log dir>/<node>.log`` (``<node>.2.log`` ... after a respawn). A node with
``respawn="true"`` that exits is started again after ``respawn_delay`` seconds (at most
``respawn_max_retries`` times when given); any other node that exits ends the launch (its last
log lines are printed) and the others are stopped. Ctrl-C or SIGTERM stops every node cleanly
(SIGINT, then SIGTERM, then SIGKILL), in reverse start order. The nodes join the ROS graph
of this shell (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE`` as set).

LAUNCHFILE is a path, or the name of a file in the package's ``launch/`` directory
(``clutch up sim.launch.xml``). Each ``<param name= value=>`` is passed in a parameter file
of its own, as ``ros2 launch`` does (``<log dir>/params/``). ``--print`` lists the node
command lines and exits (parameter files in ``<log dir>/params`` with ``--log-dir``, else in a
new ``/tmp/clutch_up_params_*``; ``--json``: also each node's resulting parameters and
respawn settings).

``--one-process`` runs can_bridge, estimator and controller in one process and one executor
(:mod:`clutch_ros.nodes.composed`, log ``<log dir>/chain.log``) for a PC that wants fewer
processes and context switches; the other nodes (rig_sim, recorder, ...) keep their own.
The separate-process layout stays the default.
"""

from __future__ import annotations

import shlex
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from clutch_ros.cli.dispatch import emit_json
from clutch_ros.cli.processes import NodeProcess, node_env
from clutch_ros.config.launch_file import (
    LaunchFileError,
    NodeEntry,
    load_launch,
    package_share,
    parse_overrides,
)

__all__ = ["CHAIN_NODES", "NODE_EXECUTABLES", "ComposedEntry", "add_parser", "one_process",
           "resolve_launch_file", "run"]

#: Executables this package installs (``setup.py`` NODES; a test keeps the two equal); each
#: runs as ``python -m clutch_ros.nodes.<name>``.
NODE_EXECUTABLES = ("can_bridge", "rig_sim", "estimator", "controller", "recorder",
                    "bag_player", "dashboard")
POLL_S = 0.2  # [s] how often the supervisor looks at its nodes


def add_parser(sub) -> None:
    """Register ``clutch up``."""
    p = sub.add_parser("up", help="start the nodes of an XML launch file (no ros2 launch "
                       "needed)", description=__doc__.split("\n\n")[0])
    p.add_argument("launch_file", metavar="LAUNCHFILE",
                   help="launch file path, or a file name in the package's launch/ directory")
    p.add_argument("arguments", nargs="*", metavar="name:=value",
                   help="launch arguments (see --show-args)")
    p.add_argument("--log-dir", help="directory of the node logs (default: "
                   "runs/up-YYYYmmdd-HHMMSS/logs)")
    p.add_argument("--print", dest="print_only", action="store_true",
                   help="print each node's command line and exit")
    p.add_argument("--show-args", action="store_true",
                   help="list the launch file's arguments and exit")
    p.add_argument("--json", action="store_true",
                   help="with --print: the nodes as JSON on stdout")
    p.add_argument("--one-process", action="store_true",
                   help="can_bridge, estimator and controller in one process and one "
                        "executor (default: a process per node)")
    p.set_defaults(func=run)


def resolve_launch_file(name: str) -> Path:
    """Return the path of launch file ``name`` (a path, or a file in ``<share>/launch``)."""
    path = Path(name)
    if path.is_file():
        return path
    if path.parent == Path("."):
        shared = package_share() / "launch" / name
        if shared.is_file():
            return shared
    raise LaunchFileError(f"no such launch file: {name}")


def _check(description) -> None:
    for node in description.nodes:
        if node.pkg != "clutch_ros":
            raise LaunchFileError(f"{description.path.name}: node {node.name}: package "
                                  f"{node.pkg} cannot be started here (only clutch_ros)")
        if node.executable not in NODE_EXECUTABLES:
            raise LaunchFileError(f"{description.path.name}: node {node.name}: clutch_ros has "
                                  f"no executable {node.executable!r} (it has "
                                  f"{', '.join(NODE_EXECUTABLES)})")
        for path in node.param_files:
            if not Path(path).is_file():
                raise LaunchFileError(f"{description.path.name}: node {node.name}: parameter "
                                      f"file {path} not found")
    names = [n.full_name for n in description.nodes]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise LaunchFileError(f"{description.path.name}: node name(s) used twice: "
                              f"{', '.join(dupes)}")


def _say(text: str) -> None:
    sys.stderr.write(f"clutch up: {text}\n")
    sys.stderr.flush()


def _on_sigterm(signum, frame):
    raise KeyboardInterrupt


def run(args) -> int:
    """Start the launch file's nodes and supervise them until one exits or we are stopped."""
    path = resolve_launch_file(args.launch_file)
    description = load_launch(path, parse_overrides(args.arguments))
    if args.show_args:
        for arg in description.args:
            default = "(required)" if arg.default is None else f"default {arg.default!r}"
            sys.stdout.write(f"{arg.name}: {arg.description} [{default}]\n")
        return 0
    _check(description)
    nodes: list = list(description.nodes)
    if getattr(args, "one_process", False):
        nodes = one_process(nodes)
    if args.print_only:
        param_dir = (Path(args.log_dir) / "params" if args.log_dir  # kept, as launch does
                     else Path(tempfile.mkdtemp(prefix="clutch_up_params_")))
        commands: list[dict[str, Any]] = [
            {"name": n.full_name, "executable": n.executable, "args": n.ros_args(param_dir),
             "parameters": n.parameters(), "respawn": n.respawn,
             "respawn_delay": n.respawn_delay, "respawn_max_retries": n.respawn_max_retries}
            for n in nodes]
        if args.json:
            emit_json(commands)
        else:
            for c in commands:
                sys.stdout.write(shlex.join([c["executable"], *c["args"]]) + "\n")
        return 0
    log_dir = Path(args.log_dir or f"runs/up-{time.strftime('%Y%m%d-%H%M%S')}/logs")
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    running: list[_Running] = []
    code = 0
    try:
        env = node_env()
        for node in nodes:
            running.append(_Running(node, env, log_dir))
            running[-1].start()
        _say(f"{len(running)} nodes running from {path}; Ctrl-C stops them")
        code = _supervise(running)
    except KeyboardInterrupt:
        _say("stopping")
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second TERM must not cut the stop
        for item in reversed(running):
            if item.proc is None or item.restart_at is not None:
                continue  # waiting for its respawn: its exit was reported then
            rc = item.proc.stop()
            if rc not in (0, -signal.SIGINT):
                _say(f"{item.proc.name} exited with code {rc}; log {item.proc.log_path}")
                code = code or 1
        signal.signal(signal.SIGTERM, previous)
    _say(f"all nodes stopped (exit code {code})")
    return code


#: the nodes ``--one-process`` runs together (clutch_ros.nodes.composed)
CHAIN_NODES = ("can_bridge", "estimator", "controller")


class ComposedEntry:
    """The chain's nodes as one launch entry: one ``composed`` process (``--one-process``).

    Behaves as a :class:`NodeEntry` for the supervisor; respawned only when every node in it
    asks for it (then with the longest delay and the fewest retries of them).
    """

    executable = "composed"

    def __init__(self, members: list[NodeEntry]) -> None:
        self.members = members
        self.full_name = "+".join(n.full_name for n in members)
        self.respawn = all(n.respawn for n in members)
        self.respawn_delay = max(n.respawn_delay for n in members)
        limits = [n.respawn_max_retries for n in members if n.respawn_max_retries >= 0]
        self.respawn_max_retries = min(limits) if limits else -1

    def ros_args(self, param_dir: Path) -> list[str]:
        """Return the ``composed`` command line: each member's ROS arguments after --node."""
        from clutch_ros.nodes.composed import composed_args  # (the CLI imports no rclpy early)

        return composed_args([(n.executable, n.ros_args(param_dir)) for n in self.members])

    def parameters(self) -> dict[str, Any]:
        """Each member's parameters, by its full name."""
        return {n.full_name: n.parameters() for n in self.members}


def one_process(nodes: list) -> list:
    """Replace the chain's nodes (:data:`CHAIN_NODES`) by one :class:`ComposedEntry`."""
    chain = [n for n in nodes if n.executable in CHAIN_NODES]
    if len(chain) < 2:
        return nodes
    at = nodes.index(chain[0])
    rest = [n for n in nodes if n.executable not in CHAIN_NODES]
    return [*rest[:at], ComposedEntry(chain), *rest[at:]]


@dataclass
class _Running:
    """A launched node: its current process, and when it is due to be respawned."""

    node: NodeEntry | ComposedEntry
    env: dict
    log_dir: Path
    proc: NodeProcess | None = None
    restart_at: float | None = None  # [s] time.monotonic() of the pending respawn
    restarts: int = 0

    def start(self) -> None:
        name = self.node.full_name
        log_name = "chain" if isinstance(self.node, ComposedEntry) else name
        self.proc = NodeProcess(log_name.strip("/").replace("/", "."),
                                self.node.ros_args(self.log_dir / "params"),
                                self.env, self.log_dir, executable=self.node.executable)
        self.restart_at = None
        _say(f"started {name} ({self.node.executable}, pid {self.proc.pid}), log "
             f"{self.proc.log_path}")

    def may_respawn(self) -> bool:
        limit = self.node.respawn_max_retries
        return self.node.respawn and (limit < 0 or self.restarts < limit)


def _supervise(running: list[_Running]) -> int:
    """Respawn nodes that ask for it; else wait until a node exits and return 1 (0 if rc 0)."""
    while True:
        time.sleep(POLL_S)
        for item in running:
            if item.restart_at is not None:
                if time.monotonic() >= item.restart_at:
                    item.restarts += 1
                    item.start()
                continue
            proc = item.proc
            if proc is None:  # not started yet
                continue
            rc = proc.returncode
            if rc is None:
                continue
            if item.may_respawn():
                proc.stop()  # closes its log
                item.restart_at = time.monotonic() + item.node.respawn_delay
                _say(f"node {item.node.full_name} exited with code {rc}; respawning in "
                     f"{item.node.respawn_delay:g} s. Last log lines:\n{proc.tail()}")
                continue
            _say(f"node {proc.name} exited with code {rc}; stopping the others. "
                 f"Last log lines:\n{proc.tail()}")
            return 0 if rc == 0 else 1
