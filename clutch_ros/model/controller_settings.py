"""The torque controller's tunables: defaults, units and ranges, checked on construction.

:class:`ControllerSettings` configures :class:`~clutch_ros.model.control.TorqueController`;
the module docstring of :mod:`clutch_ros.model.control` describes the control law, the lead,
the integral trim and the caution these settings tune. The controller node's
``controller.*`` parameters, ``clutch demo`` and ``clutch closed-loop`` take their defaults
from here: written once, in the component's own config. Units: time [s], pressure [Pa],
torque [N m], rates per second; fractions and gains are dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clutch_ros.model.errors import ModelError

__all__ = ["ControllerSettings"]


@dataclass(frozen=True)
class ControllerSettings:
    """Tunables of :class:`~clutch_ros.model.control.TorqueController` (node parameters, SI).

    Attributes:
        period: control period [s]
        min_pressure, max_pressure: command limits [Pa]
        rise_rate_limit: maximum pressure rise [Pa/s]; below the pump's kick threshold
            (about 100 bar/s, thesis §5.1.1) so steps do not overshoot
        fall_rate_limit: maximum pressure fall [Pa/s] (fail-safe zeroing bypasses it)
        torque_ramp_rate: slew of the torque target [N m/s] (request ramping)
        lead_time: the target is advanced by lead_time x the request slope [s] (rising)
        fall_lead_time: the same on a falling request [s]. On a falling request the pump's
            lag, the transport delay and the pack's spline hysteresis at the reversal add
            up, and a longer lead helps there (``clutch closed-loop --full --delay 0.1``,
            live-like: the ramp-down's top 1.059 with 0.2 s, 1.049 with 0.3 s), but it
            undershoots the end of a steep ramp-down (the quick profile's: 92.6 % within
            ±10 % with 0.3 s, 100 % with 0.2 s), so the default stays ``lead_time``'s
        lead_max_rate: bound of the request slope used by the lead [N m/s]
        slope_window: window of the request slope [s]
        overshoot_margin: guard, never above inverse((1 + margin) x request) [1]
        correction_gain: weight of the spline-friction correction [1]
        trim_rate: integral gain of the torque trim, 1/its time constant [1/s]; 0 = off
        trim_limit: bound of the trim, a fraction of the request [1]
        trim_delay: the trim holds this long after a step of the request [s]
        trim_settle_time: after ``trim_delay`` and up to this long after a step, the trim
            also holds while the error it integrates is beyond its bounds (``trim_limit``
            around the caution's centre): the step's transient is not over.
            Live, a pressure path 0.1-0.2 s late moved the pack's transient past
            ``trim_delay``, the trim integrated it to +3.5 bar and the first step overshot to
            1.17; this ties the hold to the measurement, and the time bound keeps a model
            error larger than ``trim_limit`` from holding it for ever [s]
        trim_hold: a torque measurement missing for up to this long holds the trim (a late
            CAN frame); longer, the trim is released (off without a measurement) [s]
        step_threshold: a request change above this fraction of the request is a step
            (ramps move by less per tick) when it is also faster than ``lead_max_rate``:
            a ramp sample published late moves by more than the fraction, but at the ramp's
            slope (live, 0.05-0.15 s gaps between the demo's ramp requests each released
            the trim for ``trim_delay``, and a ramp-down then overshot by 13 %) [1]
        scale_tolerance: re-invert with a new friction scale when it moved by this [1]
        trim_reset_on_change: release the trim at every step of the request (the model's
            residual error depends on the operating point and on the direction the pack
            last moved, so a trim learned on one plateau is wrong after a step)
        scale_hold: take a new adapted friction scale only when the request changes (or is
            0), never during a hold, where the trim holds the torque: the adaptation and the
            trim then never act on the same error at once
        uncertainty_margin: while the trim can act (a torque measurement, ``trim_rate`` > 0),
            invert the model with the friction scale at its upper confidence bound
            ``s + uncertainty_margin · σ_s`` (σ_s the adaptation's standard deviation), so an
            unlearned μ is approached from below; 0 = the best estimate ``s`` [number of σ]
        uncertainty_range: the start: the friction scale may be anywhere in
            ``s ± uncertainty_range · σ_s`` (the prior's 2 σ before anything is learned), and
            no μ in it may overshoot by more than ``overshoot_margin``: while the trim can
            act the scale inverted is at least ``(s + range σ) / (1 + overshoot_margin)``
            and the trim's bounds reach every plant of the range; 0 = off [number of σ]
        start_trim_delay: ``trim_delay`` of a step taken with that start's caution (the
            torque then settles well below the request, so the trim may act sooner: 0.8 s
            cost the start at the preset's μ 0.6 % of the quick profile's time within
            ±10 %, 0.5 s nothing; ``clutch closed-loop``) [s]

    """

    period: float = 0.01
    min_pressure: float = 0.0
    max_pressure: float = 40e5
    rise_rate_limit: float = 90e5
    fall_rate_limit: float = 400e5
    torque_ramp_rate: float = 4000.0
    lead_time: float = 0.2
    fall_lead_time: float = 0.2
    lead_max_rate: float = 1000.0
    slope_window: float = 0.1
    overshoot_margin: float = 0.05
    correction_gain: float = 1.0
    trim_rate: float = 8.0
    trim_limit: float = 0.15
    trim_delay: float = 0.8
    trim_settle_time: float = 1.5
    trim_hold: float = 0.25
    step_threshold: float = 0.02
    scale_tolerance: float = 1e-3
    trim_reset_on_change: bool = True
    scale_hold: bool = True
    uncertainty_margin: float = 0.5
    uncertainty_range: float = 2.0
    start_trim_delay: float = 0.5

    def __post_init__(self) -> None:
        checks = {"period": self.period > 0.0, "rise_rate_limit": self.rise_rate_limit > 0.0,
                  "fall_rate_limit": self.fall_rate_limit > 0.0,
                  "torque_ramp_rate": self.torque_ramp_rate > 0.0,
                  "lead_time": self.lead_time >= 0.0,
                  "fall_lead_time": self.fall_lead_time >= 0.0,
                  "lead_max_rate": self.lead_max_rate >= 0.0,
                  "slope_window": self.slope_window > 0.0,
                  "overshoot_margin": self.overshoot_margin >= 0.0,
                  "correction_gain": self.correction_gain >= 0.0,
                  "trim_rate": self.trim_rate >= 0.0,
                  "trim_limit": 0.0 <= self.trim_limit <= 1.0,
                  "trim_delay": self.trim_delay >= 0.0,
                  "trim_settle_time": self.trim_settle_time >= 0.0,
                  "trim_hold": self.trim_hold >= 0.0,
                  "step_threshold": self.step_threshold >= 0.0,
                  "scale_tolerance": self.scale_tolerance >= 0.0,
                  "uncertainty_margin": self.uncertainty_margin >= 0.0,
                  "uncertainty_range": self.uncertainty_range >= 0.0,
                  "start_trim_delay": self.start_trim_delay >= 0.0,
                  "min_pressure": 0.0 <= self.min_pressure <= self.max_pressure}
        for name, ok in checks.items():
            if not ok or not math.isfinite(getattr(self, name)):
                raise ModelError(f"controller setting {name} out of range: "
                                 f"{getattr(self, name)!r}")
