"""Node parameters: one declared ROS parameter per :class:`ParamSpec` (unit, range, description).

Every node module lists its tunables as ``PARAMS``; :func:`declare_params` declares them with
descriptors (ranges, read-only with the reason in the description) and :func:`format_help`
prints them for ``--help`` without starting ROS.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

__all__ = ["DBC_FILE_PARAM", "HARDWARE_ID_PARAM", "ParamSpec", "declare_params", "format_help",
           "help_requested"]


@dataclass(frozen=True)
class ParamSpec:
    """One declared ROS parameter: name, default, unit, description and allowed range.

    ``minimum``/``maximum`` become the descriptor's floating-point or integer range (ROS
    rejects out-of-range ``ros2 param set`` calls on its own); ``choices`` are checked by the
    node's parameter callback.
    """

    name: str
    default: object
    description: str
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    #: the value may be of another type than the default's: a CAN channel is a name
    #: (``can0``) or a number (Vector, Kvaser: ``0``), and ROS reads ``-p can.channel:=0`` and
    #: a launch file's ``value="0"`` as an integer
    dynamic_typing: bool = False

    def describe(self) -> str:
        """Return a one-line human description with unit and range."""
        unit = f" [{self.unit}]" if self.unit else ""
        rng = ""
        if self.minimum is not None or self.maximum is not None:
            rng = f" range {self.minimum if self.minimum is not None else '-inf'}" \
                  f"..{self.maximum if self.maximum is not None else 'inf'}"
        if self.choices:
            rng = f" one of {'|'.join(self.choices)}"
        return f"{self.name}{unit}: {self.description} (default {self.default!r}{rng})"


#: The rig a node serves, for its /diagnostics hardware_id (the launch files set it).
HARDWARE_ID_PARAM = ParamSpec(
    "diagnostics.hardware_id", "", "hardware_id of this node's /diagnostics status: the rig "
    "it serves (CAN interface:channel, or 'simulated rig'); empty: the node name; read-only: "
    "fixed for the node's life", read_only=True)


#: The rig CAN database, the same parameter in every node that speaks the rig's bus
#: (``can_bridge``, ``rig_sim``; the launch files pass both their ``dbc_file``).
DBC_FILE_PARAM = ParamSpec(
    "bridge.dbc_file", "", "rig DBC file; empty: the package's params/rig.dbc (the source "
    "checkout's, or the installed share's found through the ament index); read-only: the "
    "database is loaded and checked at configure (rig_sim: at start)", read_only=True)


def declare_params(node, specs: Iterable[ParamSpec], overrides: dict | None = None) -> dict:
    """Declare ``specs`` on ``node`` with descriptors and ranges; return {name: value}."""
    values = {}
    for spec in specs:
        descriptor = ParameterDescriptor(description=spec.describe(), read_only=spec.read_only,
                                         dynamic_typing=spec.dynamic_typing)
        default = (overrides or {}).get(spec.name, spec.default)
        if isinstance(spec.default, bool):
            pass
        elif isinstance(spec.default, int) and (spec.minimum is not None
                                                or spec.maximum is not None):
            descriptor.integer_range = [IntegerRange(
                from_value=int(spec.minimum if spec.minimum is not None else -2**31),
                to_value=int(spec.maximum if spec.maximum is not None else 2**31 - 1), step=0)]
        elif isinstance(spec.default, float) and (spec.minimum is not None
                                                  or spec.maximum is not None):
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(spec.minimum if spec.minimum is not None else -1e300),
                to_value=float(spec.maximum if spec.maximum is not None else 1e300), step=0.0)]
        param = node.declare_parameter(spec.name, default, descriptor)
        values[spec.name] = param.value
    return values


def help_requested(argv: Sequence[str]) -> bool:
    """Return True when ``-h``/``--help`` appears before any ``--ros-args``."""
    for arg in argv:
        if arg == "--ros-args":
            return False
        if arg in ("-h", "--help"):
            return True
    return False


def format_help(name: str, doc: str, specs: Iterable[ParamSpec]) -> str:
    """Return the ``--help`` text of node ``name``."""
    lines = [f"usage: ros2 run clutch_ros {name} [--executor lean|single|events] [--ros-args "
             "--params-file FILE -p NAME:=VALUE -r __ns:=/NS ...]", "", doc.strip(), "",
             "parameters:"]
    lines += [f"  {spec.describe()}" for spec in specs]
    return "\n".join(lines) + "\n"
