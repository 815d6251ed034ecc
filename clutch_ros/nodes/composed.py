"""Several clutch_ros nodes in one process and one executor (``clutch up --one-process``).

``python -m clutch_ros.nodes.composed [--executor KIND] --node can_bridge --ros-args ...
--node estimator --ros-args ... --node controller --ros-args ...`` builds each node with its
own ROS arguments (name and namespace remaps, parameter files, ``-p``), as if it ran alone,
and spins them all in one executor (the nodes' default, or ``--executor KIND`` as a node
takes it, :mod:`clutch_ros.nodes.runner`): one process, one DDS participant, no context switch
between the bridge, the estimator and the controller. Signals, ``--help``, bad settings
(``composed: error: ...``, exit 2) and the clean shutdown are those of one node
(:func:`clutch_ros.nodes.runner.run_nodes`); the lifecycle bridge's ``autostart`` acts when
it is built, as in its own process. The real-time options (``rt.*``) of each node are applied
to the whole process in start order (the last node's win where they differ).

How each node gets its own arguments: the node classes take none (``super().__init__(NAME)``;
the lifecycle bridge calls ``Node.__init__`` by name), so while one node is built,
``Node.__init__`` is wrapped once to add ``cli_args`` and ``use_global_arguments=False``;
the wrapper is removed before the next node is built. The separate-process layout (one node
per process, ``clutch up`` without ``--one-process``) stays the default.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Sequence
from contextlib import contextmanager

from rclpy.node import Node

from clutch_ros.nodes.runner import executor_option, run_nodes

__all__ = ["COMPOSABLE", "NODE_FLAG", "composed_args", "main", "parse_groups"]

NAME = "composed"
NODE_FLAG = "--node"
#: executable -> node class of the nodes that may share a process
COMPOSABLE = {"can_bridge": "CanBridgeNode", "estimator": "EstimatorNode",
              "controller": "ControllerNode", "rig_sim": "RigSimNode"}


def composed_args(groups: Sequence[tuple[str, Sequence[str]]]) -> list[str]:
    """Return the command line of :func:`main` for ``[(executable, ros args), ...]``."""
    out: list[str] = []
    for executable, args in groups:
        out += [NODE_FLAG, executable, *args]
    return out


def parse_groups(argv: Sequence[str]) -> list[tuple[str, list[str]]]:
    """Split ``--node EXEC args... --node EXEC args...``; ValueError when malformed."""
    groups: list[tuple[str, list[str]]] = []
    it = iter(argv)
    for arg in it:
        if arg == NODE_FLAG:
            executable = next(it, None)
            if executable not in COMPOSABLE:
                raise ValueError(f"--node {executable}: not a composable node (one of "
                                 f"{', '.join(COMPOSABLE)})")
            groups.append((executable, []))
        elif not groups:
            raise ValueError(f"expected {NODE_FLAG} EXECUTABLE first, got {arg!r}")
        else:
            groups[-1][1].append(arg)
    if not groups:
        raise ValueError(f"no node given ({NODE_FLAG} EXECUTABLE [--ros-args ...], repeated)")
    return groups


@contextmanager
def _node_arguments(cli_args: list[str]):
    """While active, the next ``Node.__init__`` call gets ``cli_args`` (module docstring)."""
    original = Node.__init__
    used: list[bool] = []

    def init(self, *args, **kwargs):
        if not used:
            used.append(True)
            kwargs.setdefault("cli_args", cli_args)
            kwargs.setdefault("use_global_arguments", False)
        original(self, *args, **kwargs)

    Node.__init__ = init  # type: ignore[method-assign]
    try:
        yield
    finally:
        Node.__init__ = original  # type: ignore[method-assign]


def _factory(executable: str, args: list[str]) -> Callable[[], Node]:
    cls = getattr(importlib.import_module(f"clutch_ros.nodes.{executable}"),
                  COMPOSABLE[executable])
    cli_args = args if "--ros-args" in args else ["--ros-args", *args] if args else []

    def build() -> Node:
        with _node_arguments(cli_args):
            return cls()

    return build


def main(args=None) -> int:
    """Console entry point: the nodes of the command line in one process (module docstring)."""
    argv = list(sys.argv[1:] if args is None else args)
    if not argv or argv[0] in ("-h", "--help"):
        sys.stdout.write(__doc__ + f"\ncomposable nodes: {', '.join(COMPOSABLE)}\n")
        return 0
    executor, argv = executor_option(argv)  # --executor KIND, as a node takes it
    try:
        groups = parse_groups(argv)
    except ValueError as err:
        sys.stderr.write(f"{NAME}: error: {err}\n")
        return 2
    return run_nodes(NAME, [_factory(e, a) for e, a in groups], [], executor)


if __name__ == "__main__":
    raise SystemExit(main())
