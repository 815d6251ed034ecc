"""Renamed ROS parameters: the old name still works, with a deprecation warning.

A node lists its renames as ``{old name: new name}`` and declares its parameters with
:func:`declare_with_renames` instead of :func:`~clutch_ros.nodes.parameters.declare_params`:

- at start (a ``--params-file`` YAML or ``-p old:=value``), a value given under the old name
  becomes the new parameter's value, with one WARN naming both; when the new name is given as
  well, the new one wins and the WARN says the old one was ignored. The new parameter's
  descriptor (range) checks the value as if it had been given under the new name, and a
  value of the wrong type stops the node with one line (a ClutchError);
- live (``ros2 param set NODE old value``, SetParameters), a pre-set callback renames the
  parameter before validation, with the same WARN, so the node sees only the new name.

The old name is not declared (``ros2 param list`` shows the new one only).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from clutch_ros.errors import ClutchError
from clutch_ros.nodes.parameters import ParamSpec, declare_params

__all__ = ["declare_with_renames"]


def _coerce(spec: ParamSpec, value):
    """Return an integer given for a floating-point parameter (``-p NAME:=9000000``) as float."""
    if isinstance(spec.default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def declare_with_renames(node, specs: Iterable[ParamSpec], renamed: Mapping[str, str]) -> dict:
    """Declare ``specs`` on ``node``, accepting the old names of ``renamed``; return values.

    ``renamed``: ``{old name: new name}``, each new name one of ``specs``.
    """
    specs = list(specs)
    by_name = {spec.name: spec for spec in specs}
    log = node.get_logger()
    given = {}  # old name -> value given at start
    for old, new in renamed.items():
        param = node.declare_parameter(old, None, ParameterDescriptor(
            dynamic_typing=True, description=f"deprecated: renamed {new}"))
        node.undeclare_parameter(old)
        if param.value is not None:
            value = _coerce(by_name[new], param.value)
            if type(value) is not type(by_name[new].default):
                raise ClutchError(f"parameter {old} (deprecated, renamed {new}) must be a "
                                  f"{type(by_name[new].default).__name__}, got {value!r}")
            given[old] = value
    values = declare_params(node, specs, {renamed[old]: v for old, v in given.items()})
    for old, value in given.items():
        new = renamed[old]
        if values[new] == value:
            log.warning(f"parameter {old} is deprecated, renamed {new}: set {new} instead "
                        f"(using {old}={value!r})")
        else:
            log.warning(f"parameter {old} is deprecated, renamed {new}: {old}={value!r} "
                        f"ignored, {new}={values[new]!r} is set as well")

    def rename(parameters: list[Parameter]) -> list[Parameter]:
        names = {p.name for p in parameters}
        out = []
        for p in parameters:
            new = renamed.get(p.name)
            if new is None or p.type_ == Parameter.Type.NOT_SET:
                out.append(p)  # not renamed, or an undeclare request: as it came
            elif new in names:
                log.warning(f"parameter {p.name} is deprecated, renamed {new}: ignored, "
                            f"{new} is set in the same request")
            else:
                value = _coerce(by_name[new], p.value)
                log.warning(f"parameter {p.name} is deprecated, renamed {new}: set {new} "
                            f"instead (setting {new}={value!r})")
                out.append(Parameter(new, value=value))
        return out

    node.add_pre_set_parameters_callback(rename)
    return values
