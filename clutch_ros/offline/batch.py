"""Independent offline jobs (one per bag) run serially, in local processes, or on Dask.

``clutch replay BAG... --jobs N`` and ``--cluster ADDRESS`` (and ``clutch fit``'s reading of
many runs) hand a picklable job and its items to :func:`run_jobs`; the results come back as a
list in input order, identical to the serial run: each job is the same deterministic
function of its item, only where it runs changes.

- ``jobs <= 1`` (and no cluster): a plain loop in this process.
- ``jobs > 1``: a :class:`concurrent.futures.ProcessPoolExecutor`. On Linux its workers are
  forked from this process, so they start in milliseconds with every module this process has
  imported already (a spawned worker would pay the ~1 s import of numpy, scipy and rosbags
  again); elsewhere they are spawned (with :mod:`clutch_ros.numeric_env`'s settings, one
  BLAS thread among them, set when unset, so N workers use N cores). Forked workers share
  the parent's settings, which the ``clutch`` command made before numpy loaded. Before the
  fork, :func:`gc.freeze` moves every object alive into the collector's permanent
  generation (Python's advice for fork without exec); they stay there, so a process that
  runs a batch and ends also skips them in its collections at exit (~0.15 s of a
  ``clutch replay`` process on the 2-core machine, benchmarks/RESULTS.md).
- ``costs`` (optional, one per item, e.g. a bag's size in bytes): the items are handed to
  the workers largest first (longest-processing-time first), so a large item does not start
  last and run alone while the other workers idle; the results still come back in input
  order. Without costs, input order.
- ``cluster``: a running Dask distributed scheduler (``tcp://host:8786``); the jobs go to its
  workers with ``Client.map`` and come back with ``Client.gather`` (input order). The bags
  must be readable under the same paths on every worker (a shared file system). Dask rather
  than Ray: Dask's scheduler/worker processes are plain Python with no daemon of their own
  (``dask scheduler`` / ``dask worker``, or a cluster manager such as dask-jobqueue for a
  test department's batch system), it pickles our module-level functions by reference, it
  is pinned in requirements.txt, and ``distributed.LocalCluster`` gives a real scheduler in
  one test process; Ray needs its own runtime (raylet, object store, GCS) and is not
  installed here.

Errors: a :class:`~clutch_ros.errors.ClutchError` or ``OSError`` raised by a job is carried
back as its one-line message and raised here as :class:`BatchJobError` (many of the package's
errors take extra constructor arguments and cannot be unpickled as they are). A cluster that
cannot be reached raises :class:`ClusterError`.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from clutch_ros import numeric_env
from clutch_ros.errors import ClutchError
from clutch_ros.offline.errors import BatchJobError, ClusterError  # re-exported: old home

__all__ = ["BatchJobError", "ClusterError", "dispatch_order", "run_jobs"]


#: Seconds to wait for a Dask scheduler to answer before giving up.
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class _Guarded:
    """Call ``func(item)``; return ``(True, value)`` or ``(False, message)`` for our errors.

    Picklable (module-level class holding a module-level function), so it runs in pool and
    cluster workers alike.
    """

    func: Callable[[Any], Any]

    def __call__(self, item: Any) -> tuple[bool, Any]:
        try:
            return True, self.func(item)
        except (ClutchError, OSError) as err:
            return False, str(err)


def _unwrap(outcomes: Sequence[tuple[bool, Any]]) -> list[Any]:
    """Values of ``outcomes`` in order; the first failure raises :class:`BatchJobError`."""
    values = []
    for ok, value in outcomes:
        if not ok:
            raise BatchJobError(value)
        values.append(value)
    return values


def _context() -> multiprocessing.context.BaseContext:
    """Fork on Linux (workers inherit the imported modules), spawn elsewhere."""
    if sys.platform.startswith("linux"):
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


def run_jobs(
    func: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    jobs: int = 1,
    cluster: str | None = None,
    costs: Sequence[float] | None = None,
) -> list[Any]:
    """Return ``[func(item) for item in items]``, run serially, in processes or on Dask.

    Args:
        func: a picklable callable (module-level function or instance of a module-level
            class) of one item; it must be deterministic for the results to equal the
            serial run's.
        items: picklable job inputs.
        jobs: local worker processes (``<= 1``: run here, serially).
        cluster: address of a running Dask distributed scheduler (``tcp://host:port``);
            overrides ``jobs``.
        costs: expected cost of each item (any unit, e.g. bytes); in processes and on a
            cluster the items are started largest first (module docstring). Results keep
            input order either way.

    Raises:
        BatchJobError: a job raised a ClutchError or OSError (its message).
        ClusterError: the scheduler cannot be reached.
        ValueError: ``jobs`` is not an integer >= 1, or ``costs`` does not match ``items``.

    """
    items = list(items)
    if not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    order = dispatch_order(costs, len(items))
    if not cluster and (jobs == 1 or len(items) <= 1):
        return [func(item) for item in items]
    outcomes = _in_order(_run_guarded(_Guarded(func), [items[i] for i in order], jobs, cluster),
                         order)
    return _unwrap(outcomes)


def dispatch_order(costs: Sequence[float] | None, count: int) -> list[int]:
    """Return the indices of ``count`` items in the order they are handed out.

    Largest cost first (ties in input order); input order without costs.

    Raises:
        ValueError: ``costs`` has not one value per item.

    """
    if costs is None:
        return list(range(count))
    costs = list(costs)
    if len(costs) != count:
        raise ValueError(f"costs has {len(costs)} values for {count} items")
    return sorted(range(count), key=lambda i: -costs[i])


def _in_order(outcomes: Sequence[Any], order: Sequence[int]) -> list[Any]:
    """Put ``outcomes`` (of the items in ``order``) back into input order."""
    ordered: list[Any] = [None] * len(order)
    for index, outcome in zip(order, outcomes):
        ordered[index] = outcome
    return ordered


def _run_guarded(func: _Guarded, items: list[Any], jobs: int,
                 cluster: str | None) -> list[tuple[bool, Any]]:
    """Map ``func`` over ``items`` on the cluster or in ``jobs`` processes, in order."""
    if cluster:
        return _on_dask(func, items, cluster)
    saved = {k: os.environ.get(k) for k in numeric_env.SETTINGS}
    numeric_env.configure()  # read by each worker's numpy if it is loaded there first
    # the objects alive now (modules, the loaded kernel, the job) leave the collector's
    # view: the workers' collections do not write to the pages they share with this
    # process, and this process's own later full collections, at exit among them, skip them
    gc.freeze()
    try:
        with ProcessPoolExecutor(max_workers=min(jobs, len(items)),
                                 mp_context=_context()) as pool:
            return list(pool.map(func, items))
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _on_dask(func: Callable[[Any], Any], items: list[Any], address: str) -> list[Any]:
    """Map ``func`` over ``items`` on the Dask scheduler at ``address``; input order."""
    try:
        # distributed is imported only for --cluster: it takes ~1 s and starts an event loop
        from distributed import Client
    except ImportError as err:  # pragma: no cover - pinned in requirements.txt
        raise ClusterError(f"--cluster needs the 'distributed' package ({err})") from err
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {err}") from err
    try:
        futures = client.map(func, items, pure=False)
        return client.gather(futures)
    finally:
        client.close()
