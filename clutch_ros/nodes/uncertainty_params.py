"""The estimator's ``uncertainty.*`` parameters: the error model of ``modelled_torque_std``.

Defaults, units and meaning come from :class:`clutch_ros.model.uncertainty.ErrorModel`
(``clutch fit`` writes identified values into the parameter file it writes). Read-only: the
error model belongs to the model parameters it was identified with.
"""

from __future__ import annotations

from clutch_ros.model.uncertainty import DEFAULTS, ErrorModel
from clutch_ros.nodes.parameters import ParamSpec

__all__ = ["UNCERTAINTY_PARAMS", "error_model"]

_D = DEFAULTS
UNCERTAINTY_PARAMS = [
    ParamSpec("uncertainty.noise", _D.noise, "torque sensor noise (1 sigma), in quadrature "
              "with the model terms of modelled_torque_std", "N m", 0.0, 1e6, read_only=True),
    ParamSpec("uncertainty.base", _D.base, "constant part of the model error in "
              "modelled_torque_std (the terms add in quadrature)", "N m",
              0.0, 1e6, read_only=True),
    ParamSpec("uncertainty.rel", _D.rel, "part of modelled_torque_std proportional to "
              "|modelled torque|", "1", 0.0, 100.0, read_only=True),
    ParamSpec("uncertainty.rate_time", _D.rate_time, "part proportional to the filtered "
              "|d modelled torque/dt|", "s", 0.0, 1e3, read_only=True),
    ParamSpec("uncertainty.stick_rel", _D.stick_rel, "extra part proportional to the torque "
              "while the clutch sticks", "1", 0.0, 100.0, read_only=True),
    ParamSpec("uncertainty.time_constant", _D.time_constant, "low-pass time constant of the "
              "torque rate", "s", 1e-4, 100.0, read_only=True),
    ParamSpec("uncertainty.stick_speed", _D.stick_speed, "|filtered slip speed| below which "
              "the clutch counts as sticking", "rad/s", 1e-6, 100.0, read_only=True),
    ParamSpec("uncertainty.max_gap", _D.max_gap, "a sample gap above this restarts the torque "
              "rate filter", "s", 1e-4, 3600.0, read_only=True),
    ParamSpec("uncertainty.rate_slip", _D.rate_slip, "part proportional to the filtered "
              "|d modelled torque/dt| over |filtered slip speed| while the clutch slips", "rad",
              0.0, 1e3, read_only=True),
    ParamSpec("uncertainty.slip_floor", _D.slip_floor, "|filtered slip speed| from which "
              "the clutch slips for the rate_slip term", "rad/s", 1e-3, 100.0, read_only=True),
    ParamSpec("uncertainty.recent_weight", _D.recent_weight, "weight of the recent measured "
              "error (low-pass of the squared standardised residual) in modelled_torque_std; "
              "0: the band ignores the torque sensor", "1", 0.0, 1.0, read_only=True),
    ParamSpec("uncertainty.recent_time_constant", _D.recent_time_constant, "low-pass time "
              "constant of the recent measured error", "s", 0.0, 100.0, read_only=True),
    ParamSpec("uncertainty.recent_scale", _D.recent_scale, "factor of the model terms of "
              "modelled_torque_std (its calibration with the recent error)", "1", 1e-6, 1e3,
              read_only=True),
    ParamSpec("uncertainty.recent_mean_weight", _D.recent_mean_weight, "weight of the recent "
              "measured offset (low-pass of the residual) in modelled_torque_std: the band is "
              "the central 95 % interval of the residual predicted around it; 0: none", "1",
              0.0, 1.0, read_only=True),
    ParamSpec("uncertainty.recent_mean_time_constant", _D.recent_mean_time_constant,
              "low-pass time constant of the recent measured offset", "s", 0.0, 100.0,
              read_only=True),
]


def error_model(cfg: dict) -> ErrorModel:
    """Return the ErrorModel of the ``uncertainty.*`` values of ``cfg`` (may raise)."""
    return ErrorModel.from_flat({k: v for k, v in cfg.items() if k.startswith("uncertainty.")})
