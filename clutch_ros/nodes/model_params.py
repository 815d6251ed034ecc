"""Model parameters as ROS parameters: declare, read back, validate runtime changes.

The model core owns the parameter table (``clutch_ros.model.PARAMETER_SPECS``: key, unit,
description, range); this module turns it into declared ROS parameters with descriptors, so
every node that runs the model (estimator, controller, rig_sim) reads the same YAML file and
rejects a bad ``ros2 param set`` with the model's own reason.
"""

from __future__ import annotations

from clutch_ros.nodes.common import ParamSpec, declare_params

__all__ = ["model_param_specs", "declare_model_params", "validated_params"]


def _attr(spec, *names, default=None):
    for name in names:
        if hasattr(spec, name):
            return getattr(spec, name)
    return default


def model_param_specs(prefix: str = "", defaults: dict | None = None) -> list[ParamSpec]:
    """Return a ParamSpec per model key, defaults from ``defaults`` (flat dotted keys)."""
    from clutch_ros.model import PARAMETER_SPECS

    specs = []
    for key, spec in PARAMETER_SPECS.items():
        default = (defaults or {}).get(key, _attr(spec, "default"))
        if default is None:
            continue
        kind = _attr(spec, "kind", default="")
        if kind == "float" and isinstance(default, int) and not isinstance(default, bool):
            default = float(default)  # a YAML "35" must still declare a double parameter
        specs.append(ParamSpec(
            name=prefix + key,
            default=default,
            description=_attr(spec, "description", default=""),
            unit=_attr(spec, "unit", default=""),
            minimum=_attr(spec, "minimum", "min"),
            maximum=_attr(spec, "maximum", "max"),
            choices=tuple(_attr(spec, "choices", default=()) or ()),
        ))
    return specs


def declare_model_params(node, preset_path: str | None = None):
    """Declare every model key on ``node`` and return the validated ``ClutchParams``.

    Defaults come from ``preset_path`` (a params YAML, usually the package's
    ``flexiforce_8.yaml``); values given by ``--params-file``/``-p`` override them.
    """
    from clutch_ros.params_file import load_flat

    defaults = load_flat(preset_path) if preset_path else {}
    values = declare_params(node, model_param_specs(defaults=defaults))
    return validated_params(values)


def validated_params(flat: dict, changes: dict | None = None):
    """Build ``ClutchParams`` from flat values plus ``changes``; raise ParameterError if bad."""
    from clutch_ros.model import ClutchParams

    merged = dict(flat)
    merged.update(changes or {})
    return ClutchParams.from_flat(merged)
