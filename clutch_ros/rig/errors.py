"""Exceptions of the simulated rig (:mod:`clutch_ros.rig`).

All derive from :class:`RigError`, itself a :class:`clutch_ros.errors.ClutchError`, so the CLI
and the ``rig_sim`` node can catch one base class.

Hierarchy::

    ClutchError
     +-- RigError
          +-- RigConfigError   (also ConfigError)  a rig parameter or scenario is invalid
"""

from __future__ import annotations

import math

from clutch_ros.errors import ClutchError, ConfigError

__all__ = ["RigConfigError", "RigError", "check_positive", "check_non_negative"]


class RigError(ClutchError):
    """Base class of every error raised by :mod:`clutch_ros.rig`."""


class RigConfigError(RigError, ConfigError):
    """A rig parameter, a scenario or a step argument is invalid."""


def check_positive(name: str, value: float, allow_inf: bool = False) -> float:
    """Return ``value`` as float if it is finite (or +inf when allowed) and > 0, else raise."""
    try:
        value = float(value)
    except (TypeError, ValueError) as err:
        raise RigConfigError(f"{name} must be a number, got {value!r}") from err
    if math.isnan(value) or value <= 0.0 or (math.isinf(value) and not allow_inf):
        raise RigConfigError(f"{name} must be positive{' (or inf)' if allow_inf else ''}, "
                             f"got {value!r}")
    return value


def check_non_negative(name: str, value: float, allow_inf: bool = False) -> float:
    """Return ``value`` as float if it is finite (or +inf when allowed) and >= 0, else raise."""
    try:
        value = float(value)
    except (TypeError, ValueError) as err:
        raise RigConfigError(f"{name} must be a number, got {value!r}") from err
    if math.isnan(value) or value < 0.0 or (math.isinf(value) and not allow_inf):
        raise RigConfigError(f"{name} must be >= 0{' (or inf)' if allow_inf else ''}, "
                             f"got {value!r}")
    return value
