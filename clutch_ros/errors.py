"""The exception hierarchy of clutch_ros.

Every error the package raises on purpose derives from :class:`ClutchError`, so callers
(the CLI, the nodes) can catch one base class and print a clear one-line message. Foreign
errors (numpy, python-can, cantools, rosbags, OS) are wrapped with ``raise ... from err``.
Subpackages define their own subclasses next to their code (model errors in
``clutch_ros.model.errors`` and so on), all rooted here.
"""


class ClutchError(Exception):
    """Base class of every error raised by clutch_ros."""


class ConfigError(ClutchError):
    """A parameter file, parameter value or command-line option is invalid."""


class DataError(ClutchError):
    """Input data (a CSV row, a CAN frame, a bag) is malformed or inconsistent."""
