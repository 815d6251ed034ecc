"""The ``clutch`` command: import, replay, fit, calibrate, the demo and the closed loop.

:mod:`clutch_ros.cli.main` builds the parser (loading only the chosen subcommand's module),
:mod:`clutch_ros.cli.dispatch` runs a subcommand with the CLI's error handling and JSON output.
One module per subcommand; the work itself is done by the layers below (see ARCHITECTURE.md).
"""

from clutch_ros import numeric_env

numeric_env.configure()  # before numpy loads: one BLAS thread, no huge-page advice

from clutch_ros.cli.main import main  # noqa: E402 - after the numpy setting above

__all__ = ["main"]
