"""Errors of the offline workflows (replay, batch jobs, fit, reports).

Most offline failures are the lower layers' errors (a bag, a parameter file, the model) and
pass through unchanged; what is the offline layer's own is how many jobs run elsewhere.

Hierarchy::

    ClutchError
    └── OfflineError            anything the offline layer itself raises
        ├── BatchJobError       a job failed in a worker process or on a Dask worker
        └── ClusterError        the Dask scheduler cannot be reached or used
"""

from __future__ import annotations

from clutch_ros.errors import ClutchError

__all__ = ["BatchJobError", "ClusterError", "OfflineError"]


class OfflineError(ClutchError):
    """Base class of the errors raised by :mod:`clutch_ros.offline` itself."""


class BatchJobError(OfflineError):
    """A job failed in a worker process or on a cluster worker (its one-line message)."""


class ClusterError(OfflineError):
    """The Dask scheduler could not be reached or used."""
