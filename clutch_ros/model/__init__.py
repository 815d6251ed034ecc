"""Model core of clutch_ros: the wet lamella-pack torque model in pure numpy/scipy.

No ROS, CAN, bag or file I/O here (``clutch_ros.config.params_file`` reads the YAML). Units are SI
(pressure Pa, force N, torque N m, speed rad/s, time s) with temperatures in °C; every module
documents its quantities. Main entry points:

- :class:`ClutchParams` (+ :data:`PARAMETER_SPECS`): validated parameters (README.md keys).
- :func:`friction_coefficient`, :func:`reference_torque` (Eq. 1), :func:`torque_capacity`.
- :func:`slip_speed_from_wheels` (Eq. 4), :func:`slip_speed_from_shafts`,
  :func:`base_speed`, :class:`SlipFilter`.
- :class:`PackModel` (Eqs. 11-27, exact ZOH) with spline laws from :func:`make_spline_law`
  (registered in :mod:`~clutch_ros.model.laws`); :func:`simulate` for series.
- :func:`pressure_for_torque` / :func:`solve_pressure`: the inverse.
- :class:`ClutchEstimator` / :func:`estimate_batch`: the per-sample estimator.
- :mod:`~clutch_ros.model.metrics` and :mod:`~clutch_ros.model.sequences` (Tables 3-4).
- :class:`TorqueController` (``control``): the control law; :func:`fit` (``identification``,
  with ``fit_data``) and :func:`calibrate` (``calibration``): grey-box fit, FlexiForce.
- :class:`ModelError` and its subclasses (``errors``).

Not exported here (import the module): ``adaptation`` (online friction-scale adaptation),
``film`` (oil film and thermal state), ``kernel`` / ``kernel_loop`` / ``kernel_box`` (the
compiled per-sample loop, numba).

Every name is imported lazily from its module on first use (``_EXPORTS``).
"""

import importlib
from typing import Any

# Imported eagerly: the function ``simulate`` shares its name with its module, and a lazy
# name would be shadowed by the submodule as soon as anything imports
# ``clutch_ros.model.simulate`` (the pack, the estimator; replay needs them anyway).
from clutch_ros.model.simulate import SimulationResult, simulate

#: Defining module -> its public names. The package imports nothing until a name is used
#: (PEP 562 ``__getattr__``), so ``clutch replay`` does not pay for scipy.optimize,
#: scipy.stats and scipy.ndimage (identification, inverse, control), ~1-3 s of start-up.
_MODULES = {
    "calibration": (
        "CalibrationComparison", "CalibrationError", "LamellaPressures",
        "SensorCalibration", "calibrate", "calibrate_same_force",
        "calibrate_same_sensor", "compare_methods", "quasi_static_mask",
    ),
    "control": (
        "ControlCommand", "ControllerOutput", "TorqueController", "command_pressure",
    ),
    "controller_settings": (
        "ControllerSettings",
    ),
    "errors": (
        "DuplicateSample", "InputError", "ModelError", "NonFiniteSample",
        "OutOfOrderSample", "ParameterError", "SampleRejected",
        "UnreachableTorqueError",
    ),
    "batch": (
        "BatchEstimator", "EstimateBatch", "estimate_batch", "warm_up",
    ),
    "estimator": (
        "ClutchEstimator", "Estimate",
    ),
    "fit_data": (
        "SAMPLE_BUDGET", "FitOptions", "FitRun", "IdentificationError",
        "NoExcitationError", "NoMeasuredTorqueError", "TooShortError",
        "UnidentifiableParameterError",
    ),
    "friction": (
        "friction_coefficient", "reference_torque", "slip_sign", "torque_capacity",
    ),
    "identification": (
        "FREE_PARAMETERS", "FitResult", "RunEvaluation", "evaluate", "fit",
        "initial_params",
    ),
    "inverse": (
        "PressureSolution", "pressure_for_torque", "pressure_for_torque_array",
        "solve_pressure",
    ),
    "laws": (
        "SplineLawInfo", "law_info", "law_names", "make_spline_law",
    ),
    "metrics": (
        "CrossCorrelation", "accuracy_summary", "cross_correlation", "hysteresis_width",
        "longest_run", "overshoot", "request_accuracy", "rmse", "torque_accuracy",
        "undershoot", "within_band",
    ),
    "pack": (
        "PackModel", "PackSample", "PackState",
    ),
    "params": (
        "NAMESPACES", "PARAMETER_SPECS", "SPLINE_LAWS", "TABLE7", "ClutchParams",
        "FrictionParams", "PackParams", "ParamSpec", "SlipParams", "SplineParams",
        "Table7Entry",
    ),
    "sequences": (
        "SEQUENCE_NAMES", "Sequence", "concatenate", "incremented_step_sequence",
        "make_sequence", "pbd_sequence", "ramp_sequence", "rpm_to_rad_s",
        "step_sequence", "table3", "table4",
    ),
    "slip": (
        "SlipFilter", "base_speed", "lowpass_series", "slip_speed_from_shafts",
        "slip_speed_from_wheels",
    ),
    "spline": (
        "SplineLaw",
    ),
    "statespace": (
        "build_state_space", "static_gain", "zoh_discretize",
    ),
}
_EXPORTS = {name: module for module, names in _MODULES.items() for name in names}

__all__ = [
    # errors
    "ModelError", "ParameterError", "InputError", "SampleRejected", "NonFiniteSample",
    "OutOfOrderSample", "DuplicateSample", "UnreachableTorqueError",
    # parameters
    "ClutchParams", "PackParams", "FrictionParams", "SplineParams", "SlipParams", "ParamSpec",
    "PARAMETER_SPECS", "NAMESPACES", "SPLINE_LAWS", "TABLE7", "Table7Entry",
    # friction, reference, slip
    "friction_coefficient", "reference_torque", "torque_capacity", "slip_sign",
    "slip_speed_from_wheels", "slip_speed_from_shafts", "base_speed", "SlipFilter",
    "lowpass_series",
    # pack
    "PackModel", "PackSample", "PackState", "SplineLaw", "make_spline_law", "SplineLawInfo",
    "law_info", "law_names",
    "build_state_space", "static_gain", "zoh_discretize", "simulate", "SimulationResult",
    # inverse
    "pressure_for_torque", "pressure_for_torque_array", "solve_pressure", "PressureSolution",
    # estimator
    "ClutchEstimator", "Estimate", "BatchEstimator", "EstimateBatch", "estimate_batch",
    "warm_up",
    # metrics
    "torque_accuracy", "request_accuracy", "overshoot", "undershoot", "rmse", "within_band",
    "cross_correlation", "CrossCorrelation", "hysteresis_width", "accuracy_summary", "longest_run",
    # sequences
    "Sequence", "SEQUENCE_NAMES", "make_sequence", "step_sequence",
    "incremented_step_sequence", "ramp_sequence", "pbd_sequence", "table3", "table4",
    "concatenate", "rpm_to_rad_s",
    # identification and FlexiForce calibration
    "CalibrationComparison", "CalibrationError", "LamellaPressures", "SensorCalibration",
    "calibrate", "calibrate_same_force", "calibrate_same_sensor", "compare_methods",
    "quasi_static_mask", "FREE_PARAMETERS", "SAMPLE_BUDGET", "FitOptions", "FitResult",
    "FitRun", "IdentificationError", "NoExcitationError", "NoMeasuredTorqueError",
    "RunEvaluation", "TooShortError", "UnidentifiableParameterError", "evaluate", "fit",
    "initial_params",
    # control
    "ControlCommand", "ControllerOutput", "ControllerSettings", "TorqueController",
    "command_pressure",
]


def __getattr__(name: str) -> Any:
    """Import the module defining ``name`` on first use (module docstring)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'clutch_ros.model' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"clutch_ros.model.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """Return the module attributes plus the lazily imported public names."""
    return sorted(set(globals()) | set(_EXPORTS))
