"""Offline closed loop: truth plant + estimator + controller, no bus and no ROS.

The same classes as the live suite (:class:`clutch_ros.rig.RigPlant`,
:class:`clutch_ros.model.ClutchEstimator`, :class:`clutch_ros.model.control.TorqueController`)
stepped deterministically: the plant at ``dt`` (1 kHz), the estimator every
``estimator_period``, the controller every ``settings.period`` on the latest estimate; one
estimator period of transport delay between plant and controller. It answers "does the
control law hold ±10 % on this plant?" in seconds and without timing noise, and is what the
controller's defaults were tuned with (``clutch closed-loop``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clutch_ros.model import ClutchEstimator
from clutch_ros.model.control import TorqueController
from clutch_ros.model.metrics import longest_run
from clutch_ros.rig.request_profile import Segment, request_at, settled_mask, slip_at

__all__ = ["ClosedLoopResult", "run_closed_loop"]

BAND = 0.10  # ±10 % accuracy band


@dataclass
class ClosedLoopResult:
    """Time series of a closed-loop run (n samples at the plant rate) and its figures.

    Arrays: ``time`` [s], ``request``, ``measured``, ``modelled`` [N m], ``pressure_command``,
    ``actuating_pressure`` [Pa], ``settled`` (bool). Figures: ``within_10pct`` (fraction of
    settled samples with measured/request in [0.9, 1.1]), ``worst_overshoot``,
    ``longest_overshoot_s`` [s].
    """

    time: np.ndarray
    request: np.ndarray
    measured: np.ndarray
    modelled: np.ndarray
    pressure_command: np.ndarray
    actuating_pressure: np.ndarray
    settled: np.ndarray
    within_10pct: float
    worst_overshoot: float
    longest_overshoot_s: float


def run_closed_loop(estimator_params, plant, profile: list[Segment], settings=None,
                    dt: float = 1e-3, estimator_period: float = 0.01) -> ClosedLoopResult:
    """Run ``profile`` through plant, estimator and controller; see the module docstring."""
    controller = TorqueController(estimator_params, settings)
    estimator = ClutchEstimator(estimator_params)
    duration = sum(seg.duration for seg in profile)
    n = int(round(duration / dt))
    est_every = max(1, int(round(estimator_period / dt)))
    ctl_every = max(1, int(round(controller.settings.period / dt)))
    out = {k: np.empty(n) for k in ("time", "request", "measured", "modelled", "command",
                                    "pressure")}
    plant.reset()
    estimate = None
    command = 0.0
    for i in range(n):
        t = i * dt
        request = request_at(profile, t)
        if i % ctl_every == 0:
            controller.set_request(t, request)
            if estimate is None:
                command = controller.fail_safe("no estimate yet").pressure
            else:
                command = controller.update(estimate.lamella_temperature,
                                            estimate.slip_speed_filtered,
                                            estimate.spline_correction).pressure
        signals = plant.step(dt, command, slip_at(profile, t))
        if i % est_every == 0:
            estimate = estimator.update(t, signals.actuating_pressure,
                                        signals.lamella_temperature, signals.slip_speed,
                                        signals.measured_torque)
        out["time"][i], out["request"][i] = t, request
        out["measured"][i], out["command"][i] = signals.measured_torque, command
        out["modelled"][i] = estimate.modelled_torque if estimate is not None else math.nan
        out["pressure"][i] = signals.actuating_pressure
    return _figures(out, profile)


def _figures(out: dict, profile) -> ClosedLoopResult:
    t, req, meas = out["time"], out["request"], out["measured"]
    settled = settled_mask(profile, t) & (req > 0.05 * req.max())
    ratio = meas[settled] / req[settled]
    over = np.zeros(t.shape, dtype=bool)
    over[settled] = ratio > 1.0 + BAND
    return ClosedLoopResult(
        t, req, meas, out["modelled"], out["command"], out["pressure"], settled,
        within_10pct=float(np.mean(np.abs(ratio - 1.0) <= BAND)) if ratio.size else math.nan,
        worst_overshoot=float(ratio.max()) if ratio.size else math.nan,
        longest_overshoot_s=longest_run(over, t))
