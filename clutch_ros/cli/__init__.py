"""The ``clutch`` command: import, replay, fit, calibrate, demo, closed-loop, dashboard, up.

:mod:`clutch_ros.cli.main` builds the parser (loading only the chosen subcommand's module),
:mod:`clutch_ros.cli.dispatch` runs a subcommand with the CLI's error handling and JSON output.
One module per subcommand: ``import_cmd``, ``replay`` (with ``replay_adapt``, its
``--adapt`` options), ``fit``, ``calibrate``, ``demo``, ``closed_loop_cmd``, ``dashboard``,
``up``; ``processes`` starts and stops node processes (``clutch demo``); ``__main__`` makes
``python -m clutch_ros.cli`` work. The work itself is done by the layers below (see
ARCHITECTURE.md). Errors are the lower layers' (every :class:`~clutch_ros.errors.ClutchError`
becomes a one-line message and exit code 2).
"""

from clutch_ros import numeric_env

numeric_env.configure()  # before numpy loads: one BLAS thread, no huge-page advice

from clutch_ros.cli.main import main  # noqa: E402 - after the numpy setting above

__all__ = ["main"]
