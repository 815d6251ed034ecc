"""Errors of the configuration layer (parameter files, presets, launch files).

Parameter files and presets raise :class:`clutch_ros.errors.ConfigError` itself, or the
model's :class:`~clutch_ros.model.errors.ParameterError` that names the key; the launch-file
reader of ``clutch up`` has its own subclass.

Hierarchy::

    ClutchError
    └── ConfigError
        └── LaunchFileError     a launch file cannot be read or leaves the supported subset
"""

from __future__ import annotations

from clutch_ros.errors import ConfigError

__all__ = ["LaunchFileError"]


class LaunchFileError(ConfigError):
    """A launch file cannot be read or uses something outside the supported subset."""
