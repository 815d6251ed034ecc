"""Model parameters as ROS parameters: declare, read back, validate runtime changes.

The model core owns the parameter table (``clutch_ros.model.PARAMETER_SPECS``: key, unit,
description, range); this module turns it into declared ROS parameters with descriptors, so
every node that runs the model (estimator, controller, rig_sim) reads the same YAML file and
rejects a bad ``ros2 param set`` with the model's own reason.
"""

from __future__ import annotations

from clutch_ros.config.params_file import load_flat
from clutch_ros.errors import ClutchError
from clutch_ros.model import NAMESPACES, PARAMETER_SPECS, ClutchParams
from clutch_ros.nodes.parameters import ParamSpec, declare_params

__all__ = ["model_param_specs", "declare_model_params", "validated_params",
           "apply_model_changes"]


def model_param_specs(prefix: str = "", defaults: dict | None = None) -> list[ParamSpec]:
    """Return a ParamSpec per model key, defaults from ``defaults`` (flat dotted keys)."""
    specs = []
    for key, spec in PARAMETER_SPECS.items():
        default = (defaults or {}).get(key, spec.default)
        if default is None:
            continue
        if spec.kind == "float" and isinstance(default, int) and not isinstance(default, bool):
            default = float(default)  # a YAML "35" must still declare a double parameter
        specs.append(ParamSpec(name=prefix + key, default=default,
                               description=spec.description, unit=spec.unit,
                               minimum=spec.minimum, maximum=spec.maximum,
                               choices=spec.choices))
    return specs


def declare_model_params(node, preset_path: str | None = None):
    """Declare every model key on ``node`` and return the validated ``ClutchParams``.

    Defaults come from ``preset_path`` (a params YAML, usually the package's
    ``flexiforce_8.yaml``); values given by ``--params-file``/``-p`` override them.
    """
    defaults = load_flat(preset_path) if preset_path else {}
    values = declare_params(node, model_param_specs(defaults=defaults))
    params = validated_params(values)
    _model_checks_ranges(node, params.to_flat())
    return params


def _model_checks_ranges(node, keys) -> None:
    """Move the ROS ranges of the model ``keys`` into their descriptors' constraint text.

    rclpy checks a descriptor's range before the set-parameters callback, so a NaN or
    out-of-range value would be refused with rclpy's message; without it the model refuses
    it with its own reason (same bounds, plus exclusive minima, finiteness, cross-key rules).
    Values from the parameter file at start-up were range-checked by rclpy already.
    """
    for key in keys:
        spec, descriptor = PARAMETER_SPECS[key], node.describe_parameter(key)
        if spec.kind != "str" and (descriptor.floating_point_range or descriptor.integer_range):
            low = ("" if spec.minimum is None
                   else f"{'>' if spec.min_exclusive else '>='} {spec.minimum}, ")
            high = "" if spec.maximum is None else f"<= {spec.maximum} "
            descriptor.additional_constraints = f"finite, {low}{high}(checked by the model)"
            descriptor.floating_point_range, descriptor.integer_range = [], []
            node.set_descriptor(key, descriptor)


def apply_model_changes(current, parameters):
    """Validate the model keys among ``parameters`` (rclpy Parameters) against ``current``.

    Returns ``(new ClutchParams or None when no model key changed, reason)``; ``reason`` is
    empty on success and the model's message when the change is refused.
    """
    changes = {p.name: p.value for p in parameters
               if p.name.split(".", 1)[0] in NAMESPACES}
    if not changes:
        return None, ""
    try:
        return validated_params(current.to_flat(), changes), ""
    except ClutchError as err:
        return None, str(err)


def validated_params(flat: dict, changes: dict | None = None):
    """Build ``ClutchParams`` from flat values plus ``changes``; raise ParameterError if bad."""
    merged = dict(flat)
    merged.update(changes or {})
    return ClutchParams.from_flat(merged)
