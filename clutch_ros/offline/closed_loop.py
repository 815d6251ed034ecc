"""Offline closed loop: truth plant + estimator + controller, no bus and no ROS.

The same classes as the live suite (:class:`clutch_ros.rig.RigPlant`,
:class:`clutch_ros.model.ClutchEstimator` or, with ``adaptation``, the
:class:`~clutch_ros.model.adaptation.AdaptiveEstimator`,
:class:`clutch_ros.model.control.TorqueController`) stepped deterministically: the plant at
``dt`` (1 kHz), the estimator every ``estimator_period``, the controller every
``settings.period`` on the latest estimate (its adapted friction scale, the scale's standard
deviation and the measured torque for the trim, as the controller node takes them from
``clutch_estimate``); one estimator
period of transport delay between plant and controller, and ``command_delay`` [s] between
the controller's command and the pump (0 by default; live, DDS, the bridge's PumpRequest cycle
and the simulated rig's own lateness add 20-100 ms on a loaded 2-core PC, which
``clutch closed-loop --delay`` reproduces without timing noise). It answers "does the control law
hold ±10 % (and the plateaus within 2 %) on this plant?" in seconds and without timing
noise, and is what the controller's defaults were tuned with (``clutch closed-loop``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from clutch_ros.model import ClutchEstimator
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimate, AdaptiveEstimator
from clutch_ros.model.control import TorqueController
from clutch_ros.model.metrics import longest_run
from clutch_ros.offline.steady_state import steady_state_error
from clutch_ros.rig.request_profile import Segment, request_at, settled_mask, slip_at

__all__ = ["ClosedLoopResult", "run_closed_loop"]

BAND = 0.10  # ±10 % accuracy band


@dataclass
class ClosedLoopResult:
    """Time series of a closed-loop run (n samples at the plant rate) and its figures.

    Arrays: ``time`` [s], ``request``, ``measured``, ``modelled`` [N m], ``pressure_command``,
    ``actuating_pressure``, ``trim_pressure`` [Pa], ``friction_scale`` and its standard
    deviation ``friction_scale_std`` [1], ``settled``
    (bool). Figures: ``within_10pct`` (fraction of settled samples with measured/request in
    [0.9, 1.1]), ``worst_overshoot``, ``longest_overshoot_s`` [s], ``steady_state_error``
    (:mod:`clutch_ros.offline.steady_state`, rated torque = the profile's largest request
    / 0.9).
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
    steady_state_error: float = math.nan
    trim_pressure: np.ndarray | None = None
    friction_scale: np.ndarray | None = None
    friction_scale_std: np.ndarray | None = None


def run_closed_loop(estimator_params, plant, profile: list[Segment], settings=None,
                    dt: float = 1e-3, estimator_period: float = 0.01,
                    adaptation: AdaptationSettings | None = None,
                    rated_torque: float | None = None,
                    command_delay: float = 0.0) -> ClosedLoopResult:
    """Run ``profile`` through plant, estimator and controller; see the module docstring.

    ``adaptation`` runs the adaptive estimator (the controller then inverts the adapted
    model and trims on the measured torque if ``settings.trim_rate`` > 0); None the plain
    estimator (the feed-forward path; the controller gets no measured torque).
    ``rated_torque`` [N m] sets the 10 % plateau threshold of ``steady_state_error``.
    ``command_delay`` [s]: each command reaches the pump this long after the controller
    issued it (rounded to plant steps; the pump keeps the previous one meanwhile).
    """
    if not (math.isfinite(command_delay) and command_delay >= 0.0):
        raise ValueError(f"command_delay must be a finite delay >= 0 s, got {command_delay!r}")
    controller = TorqueController(estimator_params, settings)
    estimator: AdaptiveEstimator | ClutchEstimator
    if adaptation is not None:
        estimator = AdaptiveEstimator(estimator_params, adaptation)
    else:
        estimator = ClutchEstimator(estimator_params)
    duration = sum(seg.duration for seg in profile)
    n = int(round(duration / dt))
    est_every = max(1, int(round(estimator_period / dt)))
    ctl_every = max(1, int(round(controller.settings.period / dt)))
    out = {k: np.empty(n) for k in ("time", "request", "measured", "modelled", "command",
                                    "pressure", "trim", "scale", "std")}
    plant.reset()
    estimate = None
    status = None
    command = trim = 0.0
    lag = int(round(command_delay / dt))
    in_flight: deque[tuple[int, float]] = deque()  # (plant step it arrives at, command [Pa])
    applied = 0.0
    for i in range(n):
        t = i * dt
        request = request_at(profile, t)
        if i % ctl_every == 0:
            controller.set_request(t, request)
            if estimate is None:
                command, trim = controller.fail_safe("no estimate yet").pressure, 0.0
            else:
                measured, scale = math.nan, 1.0
                if status is not None:
                    controller.set_model_scale(status.friction_scale, status.spline_gain_scale,
                                               status.friction_scale_std)
                    measured, scale = estimate.measured_torque, status.friction_scale
                ctl = controller.update(estimate.lamella_temperature,
                                        estimate.slip_speed_filtered,
                                        estimate.spline_correction, measured,
                                        estimate.modelled_torque, scale)
                command, trim = ctl.pressure, ctl.trim_pressure
            in_flight.append((i + lag, command))
        while in_flight and in_flight[0][0] <= i:
            applied = in_flight.popleft()[1]
        signals = plant.step(dt, applied, slip_at(profile, t))
        if i % est_every == 0:
            res = estimator.update(t, signals.actuating_pressure, signals.lamella_temperature,
                                   signals.slip_speed, signals.measured_torque)
            if isinstance(res, AdaptiveEstimate):  # (adaptation is not None)
                estimate, status = res.estimate, res.adaptation
            else:
                estimate = res
        out["time"][i], out["request"][i] = t, request
        out["measured"][i], out["command"][i] = signals.measured_torque, command
        out["modelled"][i] = estimate.modelled_torque if estimate is not None else math.nan
        out["pressure"][i] = signals.actuating_pressure
        out["trim"][i] = trim
        out["scale"][i] = status.friction_scale if status is not None else 1.0
        out["std"][i] = status.friction_scale_std if status is not None else 0.0
    rated = rated_torque if rated_torque is not None else \
        max(max(seg.start, seg.end) for seg in profile) / 0.9
    return _figures(out, profile, rated)


def _figures(out: dict, profile, rated: float) -> ClosedLoopResult:
    t, req, meas = out["time"], out["request"], out["measured"]
    settled = settled_mask(profile, t) & (req > 0.05 * req.max())
    ratio = meas[settled] / req[settled]
    over = np.zeros(t.shape, dtype=bool)
    over[settled] = ratio > 1.0 + BAND
    return ClosedLoopResult(
        t, req, meas, out["modelled"], out["command"], out["pressure"], settled,
        within_10pct=float(np.mean(np.abs(ratio - 1.0) <= BAND)) if ratio.size else math.nan,
        worst_overshoot=float(ratio.max()) if ratio.size else math.nan,
        longest_overshoot_s=longest_run(over, t),
        steady_state_error=steady_state_error(profile, t, meas, rated),
        trim_pressure=out["trim"], friction_scale=out["scale"],
        friction_scale_std=out["std"])
