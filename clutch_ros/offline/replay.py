"""Offline replay: the estimator over a bag's RigState stream, and its ClutchEstimate output.

The back end of ``clutch replay`` (and of the golden regression data and the benchmark):

1. :func:`~clutch_ros.bag.reader.read_rig_states` reads the stream into numpy columns;
2. :func:`clutch_ros.model.estimate_batch` runs the estimator over it, identical to the
   live estimator node's per-sample ``ClutchEstimator.update()`` (rejected samples skipped
   the same way). Stamps are converted to seconds exactly as the node does
   (:func:`clutch_ros.interfaces.stamp_to_s`), so both see bit-identical time steps;
3. :func:`write_estimates` writes one ``ClutchEstimate`` per sample the node would publish
   (accepted, finite torque) with the input's header stamp and frame id, as the node does,
   every field of :data:`clutch_ros.interfaces.ESTIMATE_FIELDS` filled as the node fills it:
   the model's outputs per sample, the adaptation fields as a node with ``adapt.enabled``
   false publishes them (``clutch replay --adapt`` writes the adaptation it ran).

Steps 1 and 2 overlap when a second core is free (``pipeline``): the estimate runs in a worker
thread on the blocks already read (:mod:`~clutch_ros.offline.streaming`), with the same result.
Deterministic: the same bag and parameters give the same bytes, streamed or not.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros import interfaces
from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.errors import BagError
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.rig_states import (
    REPLAY_FIELDS,
    RigStateArrays,
    model_inputs,
    read_rig_states,
)
from clutch_ros.bag.typestore import CLUTCH_ESTIMATE_TYPE, Typestore
from clutch_ros.bag.writer import BagWriter
from clutch_ros.model import accuracy_summary, estimate_batch
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimator
from clutch_ros.model.uncertainty import (
    DEFAULTS,
    ErrorModel,
    coverage,
    fit_error_model,
    phases,
    torque_std,
)
from clutch_ros.offline.streaming import StreamedEstimate, spare_core

__all__ = [
    "ESTIMATE_FIELDS",
    "ReplayJob",
    "ReplayResult",
    "estimate_layout",
    "fit_error_model_on_bags",
    "fit_error_model_on_series",
    "published_rows",
    "replay_bag",
    "stamps_s",
    "uncertainty_summary",
    "write_estimates",
]

#: EstimateBatch arrays written into each ClutchEstimate (same names as the message): the
#: numeric model outputs of :data:`clutch_ros.interfaces.ESTIMATE_FIELDS`.
ESTIMATE_FIELDS = interfaces.estimate_fields("estimate", ("float64", "float64[]", "bool"))


@dataclass
class ReplayResult:
    """One replayed bag.

    Attributes:
        bag: the input bag.
        rig: its RigState columns.
        batch: the model's ``EstimateBatch`` (one row per input sample, NaN where rejected).
        summary: ``samples``, ``accepted``, ``skipped``, ``law``, ``rmse_nm``,
            ``reference_rmse_nm``, ``within_10pct`` (and ``reference_within_10pct`` of the
            Eq. 1 reference), ``max_accuracy``, ``min_accuracy``, ``read_s`` and
            ``estimate_s`` [s], ``streamed`` (the estimate overlapped the read; then
            ``read_s`` includes the overlapped part of the estimate and ``estimate_s`` is
            what was left after the read), ``streamed_pieces`` (how many pieces).
        params: the model parameters it ran with (None when not known).
        torque_std: ``modelled_torque_std`` [N m] per input sample, as the node computes it
            (:func:`clutch_ros.model.uncertainty.torque_std`; None when not computed).

    """

    bag: Path
    rig: RigStateArrays
    batch: Any
    summary: dict[str, Any] = field(default_factory=dict)
    params: Any = None
    torque_std: Any = None


def stamps_s(rig: RigStateArrays) -> np.ndarray:
    """Header stamps [s] computed as the node does: ``sec + nanosec * 1e-9`` (float64)."""
    return model_inputs(rig.columns)[0]


def published_rows(batch: Any) -> np.ndarray:
    """Rows the live node publishes: accepted samples with a finite modelled torque."""
    return np.asarray(batch.accepted, dtype=bool) & np.isfinite(batch.modelled_torque)


def replay_bag(
    bag: str | Path,
    params: Any,
    *,
    topic: str | None = None,
    store: Typestore | None = None,
    fields: Any = None,
    per_lamella: bool = True,
    pipeline: bool | None = None,
    error_model: ErrorModel | None = None,
) -> ReplayResult:
    """Run the estimator with ``params`` over the RigState stream of ``bag``.

    ``error_model``: the torque uncertainty model (default
    :data:`~clutch_ros.model.uncertainty.DEFAULTS`); the summary gains its 95 % band
    coverage (:func:`uncertainty_summary`).

    ``fields``: the RigState fields read into ``result.rig`` (default every field;
    :data:`~clutch_ros.bag.rig_states.REPLAY_FIELDS` is what the estimate needs, a smaller
    and faster read). ``per_lamella`` False: the batch has no per-lamella force arrays (two
    (n, N) arrays fewer; nothing written or plotted needs them). ``pipeline``: estimate
    while reading (module docstring); default: when this process has a second core.

    Raises:
        BagError: no RigState topic, or no messages; plus everything
            :func:`~clutch_ros.bag.reader.read_rig_states` raises.

    """
    path = Path(bag)
    streamed = StreamedEstimate(params, per_lamella) if (
        spare_core() if pipeline is None else pipeline) else None
    start = time.perf_counter()
    try:
        rig = read_rig_states(path, topic, store=store, fields=fields, on_block=streamed)
    except BaseException:
        if streamed is not None:
            streamed.close()
        raise
    read_s = time.perf_counter() - start
    start = time.perf_counter()
    batch = streamed.result() if streamed is not None else None
    if len(rig) == 0:
        raise BagError(path, f"no RigState messages on {rig.topic}")
    if batch is None:  # not streamed, or the read reordered the blocks
        t, p, temp, omega, measured = model_inputs(rig.columns)
        batch = estimate_batch(params, t, p, temp, omega, measured, on_reject="skip",
                               per_lamella=per_lamella)
    estimate_s = time.perf_counter() - start
    ok = batch.accepted
    summary = accuracy_summary(
        batch.measured_torque, batch.modelled_torque, batch.reference_torque, where=ok
    )
    summary.update(
        bag=str(path),
        law=params.spline.law,
        samples=len(rig),
        streamed=streamed is not None and streamed.valid,
        streamed_pieces=streamed.pieces if streamed is not None and streamed.valid else 0,
        accepted=int(ok.sum()),
        skipped=int((~ok).sum()),
        read_s=read_s,
        estimate_s=estimate_s,
    )
    std = torque_std(error_model or DEFAULTS, stamps_s(rig), batch.modelled_torque,
                     batch.slip_speed_filtered, batch.measured_torque)
    summary.update(uncertainty_summary(rig, batch, std))
    return ReplayResult(path, rig, batch, summary, params, std)


def uncertainty_summary(rig: RigStateArrays, batch: Any, std: np.ndarray) -> dict[str, Any]:
    """Return the coverage of the 95 % band ``modelled_torque +- 1.96 std`` of one bag.

    Over the :func:`published_rows` with a measured torque: ``coverage_95`` (all),
    ``coverage_95_transient`` and ``coverage_95_steady`` (the phases of
    :func:`clutch_ros.model.uncertainty.phases`: transient within 1 s after the actuating
    pressure moved faster than 20 % of the bag's range per second (over 0.1 s) or the slip
    reversed beyond +-0.3 rad/s; steady otherwise; NaN for a phase without samples), the
    sample counts, and ``torque_std_mean_nm`` [N m].
    """
    rows = published_rows(batch)
    t = stamps_s(rig)
    transient = phases(t, batch.actuating_pressure, batch.slip_speed_filtered)
    out = coverage(np.where(rows, batch.measured_torque, np.nan), batch.modelled_torque, std,
                   transient)
    finite = rows & np.isfinite(std)
    out["torque_std_mean_nm"] = float(np.mean(std[finite])) if finite.any() else float("nan")
    return out


@dataclass(frozen=True)
class ReplayJob:
    """One bag of ``clutch replay`` as a picklable job (:func:`clutch_ros.offline.batch.run_jobs`).

    Called with ``(bag, out)``: replays ``bag`` with ``params``, writes the estimates to
    ``out`` (unless None, with ``storage``; ``topic``: the RigState topic, default the bag's
    only one; ``pipeline``: as :func:`replay_bag`, False in pool and cluster workers;
    ``error_model``: the torque uncertainty model, as :func:`replay_bag`) and
    returns ``(summary, result)``: the summary
    gains ``seconds`` (wall time of this bag [s]), ``samples_per_s`` and, when written,
    ``estimates_written`` and ``output``; ``result`` is the whole :class:`ReplayResult` when
    ``keep_result`` (a report needs it), else None (only the summary travels back).
    """

    params: Any
    storage: str = "mcap"
    keep_result: bool = False
    topic: str | None = None
    pipeline: bool | None = None
    error_model: Any = None

    def __call__(self, item: tuple[Path, Path | None]) -> tuple[dict[str, Any], Any]:
        """Replay one ``(bag, out)`` pair."""
        bag, out = item
        start = time.perf_counter()
        # a report plots every field; otherwise read only what the estimate needs
        fields = None if self.keep_result else REPLAY_FIELDS
        result = replay_bag(bag, self.params, topic=self.topic, fields=fields,
                            per_lamella=self.keep_result or out is not None,
                            pipeline=self.pipeline, error_model=self.error_model)
        summary = result.summary
        seconds = time.perf_counter() - start
        summary.update(seconds=seconds, samples_per_s=summary["samples"] / max(seconds, 1e-9))
        if out is not None:
            summary["estimates_written"] = write_estimates(out, result, storage=self.storage)
            summary["output"] = str(out)
        return summary, (result if self.keep_result else None)


def write_estimates(
    out: str | Path,
    result: ReplayResult,
    *,
    storage: str = "mcap",
    compression: str = "none",
    extra_columns: dict[str, np.ndarray] | None = None,
) -> int:
    """Write the ClutchEstimate stream of ``result`` to a new bag on ``/clutch_estimate``.

    One message per :func:`published_rows` row; header stamp and frame id of its input
    sample, bag timestamp = header stamp. ``extra_columns`` adds further numeric message
    fields, one value per published row (the adaptive replay's ``friction_scale`` ...).

    Returns:
        the number of messages written.

    """
    batch = result.batch
    serializer, rows, stamps, columns = estimate_layout(result)
    columns.update(extra_columns or {})
    custom = {"clutch_ros.replay_of": str(result.bag), "clutch_ros.spline_law": batch.spline_law}
    with BagWriter(
        out, storage=storage, compression=compression, delete_on_error=True, custom_data=custom
    ) as writer:
        topic = writer.add_topic(interfaces.CLUTCH_ESTIMATE.absolute, CLUTCH_ESTIMATE_TYPE)
        return write_columns(writer, topic, serializer, stamps, columns)


def estimate_layout(
    result: ReplayResult,
) -> tuple[TemplateSerializer, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Return how the ClutchEstimate stream of ``result`` is serialized, one place for all.

    Used by :func:`write_estimates` and by the dashboard's bag playback, so both produce the
    same bytes for the same sample.

    Returns:
        ``(serializer, rows, stamps_ns, columns)``: the message layout (frame id of the
        first input, the law's name, one force per lamella); the indices of the
        :func:`published_rows` in the RigState arrays; their header stamps [ns since epoch];
        the :data:`ESTIMATE_FIELDS` columns of those rows.

    """
    batch = result.batch
    rows = np.flatnonzero(published_rows(batch))
    n_lamellas = batch.lamella_normal_force.shape[1]
    serializer = TemplateSerializer(
        CLUTCH_ESTIMATE_TYPE,
        frame_id=_first_frame_id(result),
        spline_law=batch.spline_law,
        lamella_normal_force=np.zeros(n_lamellas),
        spline_friction_force=np.zeros(n_lamellas),
    )
    columns = {name: getattr(batch, name)[rows] for name in ESTIMATE_FIELDS}
    std = result.torque_std
    columns["modelled_torque_std"] = (np.full(rows.size, np.nan) if std is None
                                      else np.asarray(std, dtype=float)[rows])
    columns.update({name: np.full(rows.size, value)
                    for name, value in _adaptation_off(result).items()})
    stamps = np.asarray(result.rig.stamp_ns, dtype=np.int64)[rows]
    return serializer, rows, stamps, columns


def _adaptation_off(result: ReplayResult) -> dict[str, float | bool]:
    """Return the ClutchEstimate adaptation fields as a node without adaptation fills them.

    The node runs an ``AdaptiveEstimator``; with ``adapt.enabled`` false its status is
    constant (scale 1 and the prior standard deviations, state ``off``), and the model is
    the replay's own. One value per field (:func:`estimate_layout` gives it every row).
    """
    if result.params is None:  # not known (an adaptive replay adds its own columns)
        return {}
    status = AdaptiveEstimator(result.params, AdaptationSettings(enabled=False)).status
    out: dict[str, float | bool] = {}
    for f in interfaces.ESTIMATE_FIELDS:
        if f.source == "adaptation":
            value = getattr(status, f.attr)
            out[f.name] = (value == f.state) if f.state else value
    return out


def _first_frame_id(result: ReplayResult) -> str:
    """Header frame id of the first RigState (the node copies each input header)."""
    rig = result.rig
    if len(rig) == 0:
        return ""
    with BagReader(result.bag) as reader:
        first = int(rig.bag_time_ns.min())
        for message in reader.messages(rig.topic, start_ns=first):
            return str(message.msg.header.frame_id)
    return ""


def fit_error_model_on_bags(bags: Any, params: Any, base: ErrorModel = DEFAULTS) -> ErrorModel:
    """Identify the torque error model on the residuals of ``params`` over ``bags``.

    Each bag is replayed as ``clutch replay`` does; the runs are joined (the rate filter
    restarts at each bag's first sample, its time step being negative or beyond
    ``max_gap``) and :func:`clutch_ros.model.uncertainty.fit_error_model` fits them.
    """
    parts: list[tuple[np.ndarray, ...]] = []
    for bag in bags:
        result = replay_bag(bag, params, fields=REPLAY_FIELDS, per_lamella=False,
                            pipeline=False)
        b = result.batch
        rows = published_rows(b)
        parts.append((stamps_s(result.rig), np.where(rows, b.modelled_torque, np.nan),
                      b.measured_torque, b.slip_speed_filtered))
    return fit_error_model_on_series(parts, base)


def fit_error_model_on_series(parts: Any, base: ErrorModel = DEFAULTS) -> ErrorModel:
    """Identify the torque error model on runs given as ``(t, modelled, measured, slip)``.

    Each part is one run's arrays (``t`` [s], torques [N m], ``slip_speed_filtered``
    [rad/s]; unpublished rows NaN in ``modelled``), e.g. of an adaptive replay; joined as
    :func:`fit_error_model_on_bags` joins its bags.
    """
    parts = list(parts)
    t, modelled, measured, slip = (np.concatenate(c) for c in zip(*parts))
    if len(parts) > 1:  # a later bag may start after the last: force the restart
        starts = np.cumsum([len(p[0]) for p in parts])[:-1]
        t = t.copy()
        for i in starts:
            t[i:] += t[i - 1] - t[i] + 2 * base.max_gap
    return fit_error_model(t, modelled, measured, slip, base)
