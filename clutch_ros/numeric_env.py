"""Settings of numpy's native libraries for clutch_ros's own processes, made before numpy loads.

The ``clutch`` command (:mod:`clutch_ros.cli`) and every node process (:mod:`clutch_ros.nodes`)
call :func:`configure` on import, before anything imports numpy, because the libraries read
these environment variables once, when they load. A value the user has set is kept.
:func:`usable_cores` is the one place that asks how many cores the work may use (a replay's
second thread, a fit's Jacobian threads).

- ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` = 1 (whichever BLAS
  numpy was built with): the model's matrices are at most ~30 x 30, far below where a second
  BLAS thread pays off, while OpenBLAS's pool threads spin after each call and take a core
  from the work that matters. Measured on the 2-core reference machine (2026-11-21 and -26,
  ``/usr/bin/time``): the estimator node's p99 latency at 1 kHz fell from 6-12 ms to
  1.7-2.1 ms (then under load); ``clutch replay --no-stream`` of four 5-minute bags used
  2.2 s of CPU in 1.62 s of wall time with the pool (a spinning second thread) and 1.55 s in
  1.55 s without, and ``--jobs 2`` ran in 1.20 s instead of 1.32 s.
- ``NUMPY_MADVISE_HUGEPAGE`` = 0: numpy advises transparent huge pages for its large arrays;
  with the kernel's THP defrag in ``madvise`` mode (the usual default) each advised 2 MB page
  is compacted synchronously. A one-hour replay (3.6 M samples, ~1.5 GB of arrays) spent
  ~0.9 s more in the kernel with the advice: 3.63 s wall against 2.94 s without (medians of
  five paired runs).
"""

from __future__ import annotations

import os

__all__ = ["SETTINGS", "configure", "usable_cores"]

#: variable -> value set unless the environment has one already
SETTINGS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
            "NUMPY_MADVISE_HUGEPAGE": "0"}


def configure() -> None:
    """Set :data:`SETTINGS` in ``os.environ`` where unset (call before numpy is imported)."""
    for name, value in SETTINGS.items():
        os.environ.setdefault(name, value)


def usable_cores() -> int:
    """Return how many cores this process may run on (its CPU affinity; the count elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1
