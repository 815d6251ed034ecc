"""The estimator's ``adapt.*`` parameters (online adaptation of the friction scale).

Defaults, units and ranges come from :class:`clutch_ros.model.adaptation.AdaptationSettings`;
:func:`adapt_settings` turns the declared values back into settings (the model validates
them and raises a ClutchError with its reason).
"""

from __future__ import annotations

from clutch_ros.model.adaptation import AdaptationSettings
from clutch_ros.nodes.parameters import ParamSpec

__all__ = ["ADAPT_PARAMS", "adapt_settings"]

_A = AdaptationSettings()
ADAPT_PARAMS = [
    ParamSpec("adapt.enabled", True, "adapt the friction scale (a multiplier of mu) online "
              "while a plausible torque measurement is present (has_measured_torque)"),
    ParamSpec("adapt.forgetting_time", _A.forgetting_time, "memory of the adaptation, in "
              "adaptation time", "s", 0.1, 1e5),
    ParamSpec("adapt.scale_min", _A.scale_min, "lower bound of the friction scale", "1",
              0.05, 1.0),
    ParamSpec("adapt.scale_max", _A.scale_max, "upper bound of the friction scale", "1",
              1.0, 20.0),
    ParamSpec("adapt.min_torque", _A.min_torque, "adapt only above this |modelled torque|",
              "N m", 0.0, 1e5),
    ParamSpec("adapt.min_slip", _A.min_slip, "adapt only above this |filtered slip speed|",
              "rad/s", 0.0, 100.0),
    ParamSpec("adapt.max_torque_rate", _A.max_torque_rate, "the friction scale adapts only "
              "while |d modelled torque/dt| stays below this (quasi-steady) ...", "N m/s",
              1.0, 1e7),
    ParamSpec("adapt.settle_time", _A.settle_time, "... for at least this long", "s",
              0.0, 60.0),
    ParamSpec("adapt.recover_time", _A.recover_time, "plausible measurements needed after a "
              "dropout or an implausible value before adapting again", "s", 0.0, 3600.0),
    ParamSpec("adapt.dropout_grace", _A.dropout_grace, "a torque measurement missing for up "
              "to this long only pauses adaptation (a late frame); longer freezes it with a "
              "diagnostic", "s", 0.0, 60.0),
    ParamSpec("adapt.measurement_std", _A.measurement_std, "standard deviation of the torque "
              "error assumed by the estimator (absolute part)", "N m", 1e-3, 1e5),
    ParamSpec("adapt.spline_gain", False, "also adapt spline.gain (ff_t and ff_v laws only; "
              "identified from the transients)"),
    ParamSpec("adapt.save_params_file", "", "set to a file path to write the adapted "
              "parameters there now (a complete parameter file)"),
]


def adapt_settings(cfg: dict) -> AdaptationSettings:
    """Return the AdaptationSettings of the ``adapt.*`` values of ``cfg`` (may raise)."""
    return AdaptationSettings(
        enabled=bool(cfg["adapt.enabled"]), forgetting_time=cfg["adapt.forgetting_time"],
        scale_min=cfg["adapt.scale_min"], scale_max=cfg["adapt.scale_max"],
        min_torque=cfg["adapt.min_torque"], min_slip=cfg["adapt.min_slip"],
        max_torque_rate=cfg["adapt.max_torque_rate"], settle_time=cfg["adapt.settle_time"],
        recover_time=cfg["adapt.recover_time"], dropout_grace=cfg["adapt.dropout_grace"],
        measurement_std=cfg["adapt.measurement_std"],
        spline_gain=bool(cfg["adapt.spline_gain"]))
