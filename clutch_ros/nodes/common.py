"""Shared plumbing of the clutch_ros nodes: parameters, QoS, stamps, help, diagnostics, main.

Every node module defines ``PARAMS`` (a list of :class:`ParamSpec`) and a Node class; its
``main(args=None)`` calls :func:`run_node`, which answers ``--help`` without starting ROS
(listing every parameter with unit, range and default), spins the node and shuts down
cleanly on SIGINT / SIGTERM.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from clutch_ros.errors import ClutchError

__all__ = [
    "LogThrottle",
    "ParamSpec",
    "Diagnostics",
    "HARDWARE_ID_PARAM",
    "declare_params",
    "help_requested",
    "make_executor",
    "format_help",
    "reliable_qos",
    "run_node",
    "sec_to_stamp",
    "sensor_qos",
    "stamp_to_sec",
]


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


class LogThrottle:
    """Let a log call through at most once per ``period_s`` (monotonic clock).

    Use instead of rclpy's ``throttle_duration_sec``: rclpy inspects the caller's source file
    on every call, throttled or not (about 1 ms), which stalls a node exactly when it is
    busiest (a burst of bad samples).
    """

    def __init__(self, period_s: float = 5.0):
        self.period_s = period_s
        self._last = -math.inf

    def ready(self) -> bool:
        """Return True (and start a new period) when a message may be logged now."""
        now = time.monotonic()
        if now - self._last >= self.period_s:
            self._last = now
            return True
        return False


def sensor_qos():
    """Return the sensor-data QoS profile (best effort, depth 5), for latest-sample readers."""
    return qos_profile_sensor_data


def reliable_qos(depth: int = 200):
    """Return a reliable, volatile QoS profile: estimates, commands and requests."""
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)


def stamp_to_sec(stamp) -> float:
    """Convert a builtin_interfaces/Time to seconds [s] (float)."""
    return stamp.sec + stamp.nanosec * 1e-9


def sec_to_stamp(seconds: float, stamp=None):
    """Fill (or create) a builtin_interfaces/Time from seconds [s]; NaN/negative give 0."""
    if stamp is None:
        from builtin_interfaces.msg import Time

        stamp = Time()
    if not math.isfinite(seconds) or seconds < 0.0:
        seconds = 0.0
    ns = int(round(seconds * 1e9))
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
    return stamp


def declare_params(node, specs: Iterable[ParamSpec], overrides: dict | None = None) -> dict:
    """Declare ``specs`` on ``node`` with descriptors and ranges; return {name: value}."""
    values = {}
    for spec in specs:
        descriptor = ParameterDescriptor(description=spec.describe(), read_only=spec.read_only)
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


#: Executor the nodes spin by default. SingleThreadedExecutor: measured by
#: ``python -m benchmarks.estimator_node`` against rclpy.experimental.EventsExecutor (figures in
#: the README); ``--executor events`` before ``--ros-args`` selects the other one.
DEFAULT_EXECUTOR = "single"

#: Logged when ``--executor events`` is chosen: what the EventsExecutor did here.
EVENTS_WARNING = ("--executor events is experimental: with the rclpy 9.1.2 wheels from PyPI "
                  "it ran no subscription or timer callbacks after the first spin and ignored "
                  "SIGINT; use the default (single) unless your rclpy build was checked with "
                  "'python -m benchmarks.estimator_node'")


def make_executor(kind: str = DEFAULT_EXECUTOR):
    """Return a new ``single`` (SingleThreadedExecutor) or ``events`` (EventsExecutor)."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    if kind == "single":
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()
    raise ValueError(f"unknown executor {kind!r} (single or events)")


def _executor_option(argv: list[str]) -> tuple[str, list[str]]:
    """Take ``--executor KIND`` (before ``--ros-args``) out of ``argv``."""
    kind = DEFAULT_EXECUTOR
    out: list[str] = []
    it = iter(argv)
    for arg in it:
        if arg == "--ros-args":
            out.append(arg)
            out.extend(it)
            break
        if arg == "--executor":
            kind = next(it, DEFAULT_EXECUTOR)
        elif arg.startswith("--executor="):
            kind = arg.split("=", 1)[1]
        else:
            out.append(arg)
    return kind, out


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
    lines = [f"usage: ros2 run clutch_ros {name} [--executor single|events] [--ros-args "
             "--params-file FILE -p NAME:=VALUE -r __ns:=/NS ...]", "", doc.strip(), "",
             "parameters:"]
    lines += [f"  {spec.describe()}" for spec in specs]
    return "\n".join(lines) + "\n"


class Diagnostics:
    """Publish one DiagnosticStatus of this node on ``/diagnostics`` about once per period.

    ``collect`` is called on each tick and returns ``(level, message, values)`` with level one
    of ``"OK"``, ``"WARN"``, ``"ERROR"``, ``"STALE"`` and values a flat mapping (rendered as
    strings).
    """

    def __init__(self, node, collect: Callable[[], tuple[str, str, dict]], period_s: float = 1.0,
                 hardware_id: str = ""):
        """Publish ``collect()`` every ``period_s`` [s].

        ``hardware_id`` names the hardware the status is about (the CAN interface and
        channel, or ``simulated rig``); empty: the node's ``diagnostics.hardware_id``
        parameter when declared (:data:`HARDWARE_ID_PARAM`), else the node name.
        """
        self._node = node
        if not hardware_id and node.has_parameter(HARDWARE_ID_PARAM.name):
            hardware_id = node.get_parameter(HARDWARE_ID_PARAM.name).value
        self.hardware_id = hardware_id or node.get_name()
        self._collect = collect
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period_s, self.publish_now)

    def publish_now(self) -> None:
        """Collect and publish one status now."""
        level, message, values = self._collect()
        status = DiagnosticStatus()
        status.level = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN,
                        "ERROR": DiagnosticStatus.ERROR,
                        "STALE": DiagnosticStatus.STALE}[level]
        status.name = f"{self._node.get_namespace().rstrip('/')}/{self._node.get_name()}"
        status.message = message
        status.hardware_id = self.hardware_id
        status.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [status]
        self._pub.publish(array)


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def run_node(name: str, doc: str, specs: Sequence[ParamSpec], factory: Callable[[], object],
             args: Sequence[str] | None = None) -> int:
    """Answer --help, or init rclpy, build the node with ``factory`` and spin until shutdown.

    Bad settings (a ClutchError or rclpy ParameterException while building the node) print
    one line ``<name>: error: ...`` and return 2, never a traceback.
    """
    argv = list(sys.argv[1:] if args is None else args)
    if help_requested(argv):
        sys.stdout.write(format_help(name, doc, specs))
        return 0
    executor_kind, argv = _executor_option(argv)


    # rclpy's own handlers (SignalHandlerOptions.ALL, the default) turn SIGINT and SIGTERM
    # into a clean shutdown even while the executor waits in C; a Python-level handler would
    # only run when some callback wakes the executor.
    rclpy.init(args=[sys.argv[0], *argv])
    node = None
    try:
        node = factory()
        executor = make_executor(executor_kind)
        if executor_kind == "events":
            node.get_logger().warning(EVENTS_WARNING)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ClutchError, ParameterException, ValueError) as err:
        if node is not None:  # an error after start-up is a bug: show it
            raise
        sys.stderr.write(f"{name}: error: {err}\n")
        return 2
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
