"""The ``clutch`` command line: one parser, subcommands loaded only when chosen.

``clutch COMMAND ...`` imports the module of COMMAND alone (the table :data:`SUBCOMMANDS`), so
``clutch replay`` never pays for the ROS, CAN or plotting imports of ``clutch demo``; only
``clutch --help`` (or a command it does not know) loads every subcommand to list them. Each
subcommand module has ``add_parser(subparsers)``, which registers its arguments and sets
``func``; :func:`~clutch_ros.cli.dispatch.dispatch` runs it with the CLI's error handling.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from clutch_ros.cli.dispatch import dispatch

__all__ = ["SUBCOMMANDS", "build_parser", "main"]

#: Subcommand name -> module under clutch_ros.cli, in the order ``--help`` lists them.
SUBCOMMANDS = {
    "import": "import_cmd",
    "replay": "replay",
    "fit": "fit",
    "calibrate": "calibrate",
    "demo": "demo",
    "closed-loop": "closed_loop_cmd",
    "dashboard": "dashboard",
    "up": "up",
}


def _chosen(argv: list[str]) -> list[str]:
    """Return the subcommands whose module the parser needs for ``argv``."""
    first = next((a for a in argv if not a.startswith("-")), None)
    return [first] if first in SUBCOMMANDS else list(SUBCOMMANDS)


def build_parser(commands=None) -> argparse.ArgumentParser:
    """Return the ``clutch`` parser with ``commands`` (default: every subcommand)."""
    parser = argparse.ArgumentParser(
        prog="clutch",
        description="Wet lamella clutch torque estimation: import rig data, replay bags "
                    "through the model, run the simulated rig end to end.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in commands or SUBCOMMANDS:
        # Imported here, by name, so that a command loads only its own dependencies.
        module = importlib.import_module(f"clutch_ros.cli.{SUBCOMMANDS[name]}")
        module.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run ``clutch`` with ``argv`` (default: sys.argv[1:]); return the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_chosen(argv))
    args, extra = parser.parse_known_args(argv)
    # `clutch up FILE --print channel:=0`: launch arguments may follow options, as with
    # `ros2 launch`; argparse stops collecting a positional list at the first option.
    if extra and getattr(args, "command", None) == "up" and all(":=" in e for e in extra):
        args.arguments = [*args.arguments, *extra]
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return dispatch(args)
