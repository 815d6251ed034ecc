"""Offline adaptive replay: the adaptive estimator over bags, saving what it learned.

The back end of ``clutch replay --adapt [--save-params FILE]``. Each bag's RigState stream
(:func:`~clutch_ros.bag.rig_states.read_rig_states`) runs sample by sample through
:class:`clutch_ros.model.adaptation.AdaptiveEstimator`, exactly as the live estimator node
runs it (same stamps in seconds, rejected samples skipped); several bags run in order through
one estimator, so what was learned on one bag carries into the next, as on a rig that records
run after run (each bag restarts the estimator's clock:
:meth:`~clutch_ros.model.adaptation.AdaptiveEstimator.reset`). The result holds the
estimates (an :class:`~clutch_ros.model.EstimateBatch`, so ``-o`` and ``--report`` work
unchanged), the adaptation's time series (scale, its standard deviation, ``adapting``,
``frozen``), the diagnostic events (each change into or out of a frozen state, with its
reason: what the node reports on ``/diagnostics``) and the replay figures.
:func:`save_adapted_params` writes a complete parameter file with the adapted values
(μ_ref, μ_min and the spline gain scaled), which the nodes and every ``clutch`` subcommand
accept; replaying with it (no adaptation: frozen) is the out-of-sample check.

Units: time [s], torque [N m]; scales are dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clutch_ros import interfaces
from clutch_ros.bag.errors import BagError
from clutch_ros.bag.rig_states import model_inputs, read_rig_states
from clutch_ros.config.params_file import write_params
from clutch_ros.model import EstimateBatch, SampleRejected, accuracy_summary
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimator
from clutch_ros.offline.replay import ReplayResult, published_rows, write_estimates

__all__ = ["ADAPTATION_FIELDS", "AdaptiveReplay", "AdaptationEvent", "adaptive_replay",
           "save_adapted_params", "write_adaptive_estimates"]

#: Adaptation columns of the result: the ClutchEstimate fields filled from the adaptation
#: (:data:`clutch_ros.interfaces.ESTIMATE_FIELDS`), the four float64 ones first.
ADAPTATION_FIELDS = interfaces.estimate_fields("adaptation")
_BATCH_SCALARS = ("modelled_torque", "reference_torque", "measured_torque", "torque_accuracy",
                  "friction_coefficient", "front_pressure", "rear_pressure",
                  "pressure_difference", "slip_speed_filtered", "actuating_pressure",
                  "lamella_temperature", "slip_speed", "compression", "spline_correction")


@dataclass(frozen=True)
class AdaptationEvent:
    """A change of the adaptation's state: at ``stamp`` [s] it became ``state`` (``reason``)."""

    stamp: float
    state: str
    reason: str


@dataclass
class AdaptiveReplay:
    """One bag replayed adaptively.

    Attributes:
        result: a :class:`~clutch_ros.offline.replay.ReplayResult` (estimates and summary;
            the summary adds ``friction_scale``, ``friction_scale_std``,
            ``spline_gain_scale``, ``spline_gain_scale_std``, ``adaptation`` (samples per
            state, dropouts, implausible) and ``events``)
        series: :data:`ADAPTATION_FIELDS` -> array, one row per input sample (NaN/False for
            rejected ones)
        events: the frozen/unfrozen transitions, in order

    """

    result: ReplayResult
    series: dict[str, np.ndarray]
    events: list[AdaptationEvent] = field(default_factory=list)


def _stack(estimates: list, accepted: np.ndarray, stamps: np.ndarray, n_lam: int,
           law: str) -> EstimateBatch:
    n = stamps.size
    cols = {name: np.full(n, np.nan) for name in _BATCH_SCALARS}
    normal = np.full((n, n_lam), np.nan)
    spline = np.full((n, n_lam), np.nan)
    flags = {name: np.zeros(n, dtype=bool) for name in ("overshoot", "undershoot",
                                                        "reinitialised")}
    rows = np.flatnonzero(accepted)
    for row, est in zip(rows.tolist(), estimates):
        for name in _BATCH_SCALARS:
            cols[name][row] = getattr(est, name)
        normal[row] = est.lamella_normal_force
        spline[row] = est.spline_friction_force
        for name in flags:
            flags[name][row] = getattr(est, name)
    return EstimateBatch(stamp=stamps.copy(), accepted=accepted, lamella_normal_force=normal,
                         spline_friction_force=spline, spline_law=law, **cols, **flags)


def adaptive_replay(bags, params, settings: AdaptationSettings | None = None, *,
                    estimator: AdaptiveEstimator | None = None,
                    drop_torque_after: float | None = None,
                    topic: str | None = None) -> list[AdaptiveReplay]:
    """Replay ``bags`` in order through one adaptive estimator; return one result per bag.

    ``estimator`` continues an existing one (its learned values), else a new one starts at
    scale 1 with ``settings``. ``drop_torque_after`` [s, from each bag's first sample]
    makes the torque measurement absent from then on (``has_measured_torque`` false), for
    checking the freeze (tests and demonstrations). ``topic`` chooses the RigState topic
    (default: the bag's only one).
    """
    ae = estimator or AdaptiveEstimator(params, settings)
    out = []
    for bag in bags:
        ae.reset()  # each bag is its own recording (own clock); the learned values stay
        path = Path(bag)
        rig = read_rig_states(path, topic)
        if len(rig) == 0:
            raise BagError(path, f"no RigState messages on {rig.topic}")
        t, _, _, _, measured = model_inputs(rig.columns)
        if drop_torque_after is not None:
            measured = np.where(t < t[0] + drop_torque_after, measured, np.nan)
        out.append(_replay_one(ae, path, rig, t, measured))
    return out


def _replay_one(ae: AdaptiveEstimator, path: Path, rig, t, measured) -> AdaptiveReplay:
    n = t.size
    accepted = np.zeros(n, dtype=bool)
    series = {name: np.full(n, np.nan) for name in ADAPTATION_FIELDS[:4]}
    series.update(adapting=np.zeros(n, dtype=bool), adaptation_frozen=np.zeros(n, dtype=bool))
    estimates, events = [], []
    frozen = ae.status.state == "frozen"
    columns = (rig.actuating_pressure.tolist(), rig.lamella_temperature.tolist(),
               rig.slip_speed.tolist(), measured.tolist())
    for i, (stamp, p, temp, omega, meas) in enumerate(zip(t.tolist(), *columns)):
        try:
            res = ae.update(stamp, p, temp, omega, meas)
        except SampleRejected:
            continue
        accepted[i] = True
        estimates.append(res.estimate)
        a = res.adaptation
        series["friction_scale"][i], series["friction_scale_std"][i] = (
            a.friction_scale, a.friction_scale_std)
        series["spline_gain_scale"][i], series["spline_gain_scale_std"][i] = (
            a.spline_gain_scale, a.spline_gain_scale_std)
        series["adapting"][i] = a.adapting
        series["adaptation_frozen"][i] = a.state == "frozen"
        if (a.state == "frozen") != frozen:
            frozen = a.state == "frozen"
            events.append(AdaptationEvent(stamp, a.state, a.reason or "adapting again"))
    params = ae.base_params
    batch = _stack(estimates, accepted, t, params.pack.lamella_count, params.spline.law)
    ok = accepted
    summary = accuracy_summary(batch.measured_torque, batch.modelled_torque,
                               batch.reference_torque, where=ok)
    status = ae.status
    summary.update(
        bag=str(path), law=params.spline.law, samples=n, accepted=int(ok.sum()),
        skipped=int((~ok).sum()),
        friction_scale=status.friction_scale, friction_scale_std=status.friction_scale_std,
        spline_gain_scale=status.spline_gain_scale,
        spline_gain_scale_std=status.spline_gain_scale_std,
        adaptation=ae.counts,
        events=[{"stamp": e.stamp, "state": e.state, "reason": e.reason} for e in events])
    return AdaptiveReplay(ReplayResult(path, rig, batch, summary), series, events)


def save_adapted_params(path, estimator: AdaptiveEstimator, source: str = "") -> Path:
    """Write the adapted parameters as a complete parameter file; return its path.

    The header records the scales, their standard deviations and where they were learned.
    """
    st = estimator.status
    header = (f"clutch_ros parameters adapted online{' on ' + source if source else ''}\n"
              f"friction scale {st.friction_scale:.5f} +- {st.friction_scale_std:.5f} "
              f"(friction.mu_ref and friction.mu_min multiplied by it)\n"
              f"spline gain scale {st.spline_gain_scale:.5f} +- "
              f"{st.spline_gain_scale_std:.5f}")
    return write_params(estimator.adapted_params(), path, header=header)


def write_adaptive_estimates(out, replay: AdaptiveReplay, *, storage: str = "mcap") -> int:
    """Write the ClutchEstimate stream of an adaptive replay, adaptation fields included."""
    rows = published_rows(replay.result.batch)
    extra = {name: replay.series[name][rows] for name in ADAPTATION_FIELDS}
    return write_estimates(out, replay.result, storage=storage, extra_columns=extra)
