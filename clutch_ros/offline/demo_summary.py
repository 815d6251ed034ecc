"""Closed-loop figures of a demo run, computed from its bag (what was recorded is what counts).

Times: rig samples carry the bus timestamp (wall clock on the simulated rig); the profile
started at ``started_at`` on the same clock, so the request in force at a sample is
``request_at(profile, stamp - started_at)``.
"""

from __future__ import annotations

import math

import numpy as np

from clutch_ros.bag.reader import BagReader
from clutch_ros.interfaces import CLUTCH_ESTIMATE, DIAGNOSTICS, PRESSURE_COMMAND, RIG_STATE
from clutch_ros.model.metrics import longest_run
from clutch_ros.offline.steady_state import plateau_errors
from clutch_ros.rig.request_profile import request_at, settled_mask

__all__ = ["DemoSeries", "closed_loop_summary", "load_series"]

BAND = 0.10  # ±10 % accuracy band (thesis)
MIN_FRACTION = 0.05  # only requests above 5 % of the maximum count


class DemoSeries:
    """Arrays of a demo bag: rig samples, estimates and commands, on profile time [s]."""

    def __init__(self, bag, profile, started_at: float):

        rig_t, meas, press = [], [], []
        est_t, model, ref, est_meas, pdiff = [], [], [], [], []
        scale, scale_std = [], []
        cmd_t, cmd_p, cmd_trim = [], [], []
        lost = []  # (log time [s], the rig's lost_time_s) from its /diagnostics
        with BagReader(bag) as reader:
            topics = [RIG_STATE.absolute, CLUTCH_ESTIMATE.absolute, PRESSURE_COMMAND.absolute]
            topics += [DIAGNOSTICS.absolute] if DIAGNOSTICS.absolute in reader.topics else []
            for topic, stamp_ns, msg in reader.messages(topics):
                if topic == DIAGNOSTICS.absolute:
                    lost += [(stamp_ns * 1e-9, float(kv.value)) for st in msg.status
                             if st.name == "/rig_sim" for kv in st.values
                             if kv.key == "lost_time_s"]
                    continue
                if topic == RIG_STATE.absolute:
                    rig_t.append(_stamp(msg))
                    meas.append(msg.measured_torque if msg.has_measured_torque else math.nan)
                    press.append(msg.actuating_pressure)
                elif topic == CLUTCH_ESTIMATE.absolute:
                    est_t.append(_stamp(msg))
                    model.append(msg.modelled_torque)
                    ref.append(msg.reference_torque)
                    est_meas.append(msg.measured_torque)
                    pdiff.append(msg.pressure_difference)
                    scale.append(msg.friction_scale)
                    scale_std.append(msg.friction_scale_std)
                else:
                    cmd_t.append(stamp_ns * 1e-9)
                    cmd_p.append(msg.pressure)
                    cmd_trim.append(msg.trim_pressure)
        self.rig_stamp = np.asarray(rig_t)
        self.est_stamp = np.asarray(est_t)
        self.rig_time = np.asarray(rig_t) - started_at
        self.measured = np.asarray(meas)
        self.pressure = np.asarray(press)
        self.request = np.array([request_at(profile, t) for t in self.rig_time])
        self.est_time = np.asarray(est_t) - started_at
        self.modelled = np.asarray(model)
        self.reference = np.asarray(ref)
        self.est_measured = np.asarray(est_meas)
        self.pressure_difference = np.asarray(pdiff)
        self.friction_scale = np.asarray(scale)
        self.friction_scale_std = np.asarray(scale_std)
        self.cmd_time = np.asarray(cmd_t) - started_at
        self.cmd_pressure = np.asarray(cmd_p)
        self.cmd_trim = np.asarray(cmd_trim)
        self.settled = settled_mask(profile, self.rig_time)
        before = [v for t, v in lost if t <= started_at]
        #: [s] real time the simulated rig dropped during the profile (it fell more than
        #: 0.1 s behind: a machine short of CPU; reports are 1 s apart). 0 when it never
        #: did; NaN when the bag holds no rig_sim report.
        self.rig_lost_time = (max(v for _, v in lost) - (before[-1] if before else 0.0)
                              if lost else math.nan)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def load_series(bag, profile, started_at: float) -> DemoSeries:
    """Read a demo bag into :class:`DemoSeries`."""
    return DemoSeries(bag, profile, started_at)


def _rmse(a, b) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else math.nan


def _coverage(rig_stamps, est_stamps) -> float:
    """Fraction of rig samples since the first estimate that got an estimate (same stamp)."""
    if not len(est_stamps):
        return 0.0
    live = rig_stamps[rig_stamps >= est_stamps.min()]
    if not len(live):
        return 0.0
    have = set(np.round(est_stamps * 1e6).astype(np.int64).tolist())
    return float(np.mean([v in have for v in np.round(live * 1e6).astype(np.int64).tolist()]))


def closed_loop_summary(bag, profile, started_at: float, rated_torque: float | None = None
                        ) -> dict:
    """Return the demo's figures (see :mod:`clutch_ros.cli.demo`) from its bag.

    ``rated_torque`` [N m] sets the 10 % threshold of the plateaus counted by
    ``steady_state_error`` (default: the profile's largest request / 0.9, the demo's).
    """
    s = load_series(bag, profile, started_at)
    peak = max(max(seg.start, seg.end) for seg in profile)
    use = s.settled & (s.request > MIN_FRACTION * peak) & np.isfinite(s.measured)
    ratio = np.where(use, s.measured / np.where(use, s.request, 1.0), np.nan)
    within = float(np.mean(np.abs(ratio[use] - 1.0) <= BAND)) if use.any() else math.nan
    worst = float(np.nanmax(ratio)) if use.any() else math.nan
    over = np.nan_to_num(ratio, nan=0.0) > 1.0 + BAND
    rated = rated_torque if rated_torque is not None else peak / 0.9
    plateaus = plateau_errors(profile, s.rig_time, s.measured, rated)
    errors = [p.error for p in plateaus]
    last = len(s.friction_scale) - 1
    return {
        "steady_state_error": (float(max(errors)) if errors and all(np.isfinite(errors))
                               else math.nan),
        "plateau_errors": [{"start_s": p.plateau.start, "end_s": p.plateau.end,
                            "request_nm": p.plateau.request, "mean_measured_nm": p.mean_measured,
                            "error": p.error, "samples": p.samples} for p in plateaus],
        "plateaus": len(plateaus),
        "friction_scale": float(s.friction_scale[last]) if last >= 0 else math.nan,
        "friction_scale_std": float(s.friction_scale_std[last]) if last >= 0 else math.nan,
        "max_trim_pa": float(np.abs(s.cmd_trim).max()) if len(s.cmd_trim) else 0.0,
        "within_10pct": within,
        "estimate_coverage": _coverage(s.rig_stamp, s.est_stamp),
        "settled_samples": int(use.sum()),
        "worst_overshoot": worst,
        # [s] profile time of the worst overshoot (where to look in torque.png)
        "worst_overshoot_time_s": (float(s.rig_time[np.nanargmax(ratio)]) if use.any()
                                   else math.nan),
        "worst_undershoot": float(np.nanmin(ratio)) if use.any() else math.nan,
        "longest_overshoot_s": longest_run(over, s.rig_time),
        "estimator_rmse_nm": _rmse(s.modelled, s.est_measured),
        "reference_rmse_nm": _rmse(s.reference, s.est_measured),
        "rig_samples": int(len(s.rig_time)),
        "estimates": int(len(s.est_time)),
        "commands": int(len(s.cmd_time)),
        "max_command_pa": float(s.cmd_pressure.max()) if len(s.cmd_pressure) else 0.0,
        "rig_lost_time_s": s.rig_lost_time,
    }
