"""Estimate while reading: the bag read and the model loop of ``clutch replay`` overlapped.

A replay is a read (numpy over the file, mostly holding the GIL) followed by the model loop
(the compiled kernel, which releases the GIL). :class:`StreamedEstimate` is given each block
as :func:`~clutch_ros.bag.rig_states.read_rig_states` decodes it (its ``on_block`` hook) and
feeds a :class:`~clutch_ros.model.batch.BatchEstimator` in one worker thread, in order, in
pieces of at least :data:`PIECE_ROWS` samples. On two cores the model loop then runs while the
rest of the bag is read, and the whole replay takes about as long as the longer of the two
instead of their sum (figures in README.md, "Speed").

Same result as estimating after the read: a BatchEstimator fed in pieces equals
:func:`~clutch_ros.model.batch.estimate_batch` (tests/model/test_batch.py), and the pieces are
the final arrays in their final order, because the reader only reorders when the log times of
its blocks are out of order, which is checked here: the stream is then abandoned and
:meth:`StreamedEstimate.result` returns None, so the caller estimates the sorted arrays in one
go (tests/offline/test_streaming.py covers both).

Where the cores are already busy (``clutch replay --jobs N``, a cluster worker) the replay
does not stream: a second thread per bag would only compete with the other bags.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from clutch_ros.bag.rig_states import model_inputs
from clutch_ros.model import BatchEstimator
from clutch_ros.numeric_env import usable_cores

__all__ = ["PIECE_ROWS", "StreamedEstimate", "spare_core"]

#: Smallest piece handed to the worker [samples]: per feed a few hundred µs of Python
#: (rejections, filter, discretisation lookup, kernel call) against ~0.5 µs per sample.
PIECE_ROWS = 1 << 16


def spare_core() -> bool:
    """Return True when this process may use more than one core (streaming can help)."""
    return usable_cores() > 1


class StreamedEstimate:
    """The ``on_block`` consumer that estimates in a worker thread (module docstring).

    Args:
        params: the estimator's parameters.
        per_lamella: keep the per-lamella force arrays (as ``estimate_batch``).

    Call it as ``on_block``; after the read, :meth:`result`, or :meth:`close` when the read
    failed (both stop the worker thread).
    """

    def __init__(self, params: Any, per_lamella: bool = True):
        self.params, self.per_lamella = params, per_lamella
        self.stream: BatchEstimator | None = None
        self.valid = True
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="clutch-estimate")
        self._futures: list[Future] = []
        self._pending: list[tuple[np.ndarray, ...]] = []
        self._rows = 0
        self._last_time: int | None = None
        self.pieces = 0  # pieces handed to the worker

    def __call__(self, part: dict[str, np.ndarray], times: np.ndarray, declared: int) -> None:
        """Take one decoded block (``read_rig_states``' ``on_block`` signature)."""
        if not self.valid or times.size == 0:
            return
        first = int(times[0])
        if (self._last_time is not None and first < self._last_time) or \
                (times.size > 1 and (np.diff(times) < 0).any()):
            self.valid = False  # the reader will sort: these pieces are not the final order
            return
        self._last_time = int(times[-1])
        if self.stream is None:
            self.stream = BatchEstimator(self.params, declared, on_reject="skip",
                                         per_lamella=self.per_lamella)
        # the inputs are converted here (copies: the block may be a view of the file)
        self._pending.append(model_inputs(part))
        self._rows += times.size
        if self._rows >= PIECE_ROWS:
            self._submit()

    def _submit(self) -> None:
        if self._pending:
            pieces, self._pending, self._rows = self._pending, [], 0
            self.pieces += 1
            self._futures.append(self._pool.submit(self._feed, pieces))

    def _feed(self, pieces: list[tuple[np.ndarray, ...]]) -> None:
        joined = [np.concatenate(cols) for cols in zip(*pieces)]
        assert self.stream is not None  # made before the first piece was submitted
        self.stream.feed(*joined)

    def close(self) -> None:
        """Abandon the stream: drop what is queued, wait for the running piece, stop."""
        self.valid = False
        self._pool.shutdown(wait=True, cancel_futures=True)

    def result(self):
        """Wait for the worker; return the EstimateBatch, or None when the stream was abandoned.

        Raises what the worker raised (a model error on the data).
        """
        try:
            if self.valid:
                self._submit()
            for future in self._futures:
                future.result()
        finally:
            self._pool.shutdown(wait=True, cancel_futures=True)
        if not self.valid or self.stream is None:
            return None
        return self.stream.result()
