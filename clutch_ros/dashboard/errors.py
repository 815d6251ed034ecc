"""Errors of the dashboard layer (Foxglove server, bag playback).

Hierarchy::

    ClutchError
    └── DashboardError        the server cannot start (port taken, bad bind address), a bag
                              without any topic the dashboard serves, a bad playback rate
"""

from __future__ import annotations

from clutch_ros.errors import ClutchError

__all__ = ["DashboardError"]


class DashboardError(ClutchError):
    """The dashboard cannot serve: bad address or port, bad rate, or nothing to serve."""
