"""How a ``clutch`` subcommand runs and reports: error handling, exit codes, JSON output.

Every subcommand prints a clear one-line error and exits non-zero on bad input (never a
traceback; set ``CLUTCH_DEBUG=1`` to see one). ``--json`` prints machine-readable results on
stdout; progress and human text go to stderr.

Exit codes: 0 success, 1 the job ran but failed its check, 2 bad input or usage, 130
interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from clutch_ros.errors import ClutchError

__all__ = ["add_batch_options", "check_batch_options", "dispatch", "emit_json", "standalone"]


def emit_json(obj) -> None:
    """Print ``obj`` as JSON on stdout (NaN and infinities written as null)."""
    sys.stdout.write(json.dumps(_clean(obj), indent=2) + "\n")


def _clean(obj):
    if isinstance(obj, float):
        return obj if obj == obj and obj not in (float("inf"), float("-inf")) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def dispatch(args) -> int:
    """Run the parsed subcommand ``args.func`` with the CLI's error handling."""
    try:
        return int(args.func(args) or 0)
    except ClutchError as err:
        if os.environ.get("CLUTCH_DEBUG"):
            raise
        sys.stderr.write(f"clutch {args.command}: error: {err}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"clutch {args.command}: interrupted\n")
        return 130
    except OSError as err:
        if os.environ.get("CLUTCH_DEBUG"):
            raise
        sys.stderr.write(f"clutch {args.command}: error: {err}\n")
        return 2


def standalone(module, command: str, argv=None) -> int:
    """Run one subcommand ``module`` as ``clutch COMMAND`` (``python -m clutch_ros.cli.X``)."""
    parser = argparse.ArgumentParser(prog="clutch")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    module.add_parser(sub)
    return dispatch(parser.parse_args([command, *(sys.argv[1:] if argv is None else argv)]))


def add_batch_options(p, what: str) -> None:
    """Register ``--jobs N`` and ``--cluster ADDRESS`` (work on ``what`` in parallel)."""
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help=f"work on N {what} at once in local processes (default 1; results "
                        "are identical to a serial run and in input order)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help=f"run the {what} on the workers of a running Dask distributed "
                        "scheduler (e.g. tcp://10.0.0.5:8786); every worker must see the "
                        "files under the same paths")


def check_batch_options(args) -> None:
    """Raise ClutchError for a bad ``--jobs`` value."""
    if args.jobs < 1:
        raise ClutchError(f"--jobs must be >= 1, got {args.jobs}")
