"""The can_bridge node's parameters: which apply live, which are read-only and why.

Live (an on-set-parameters callback validates, the node applies accepted values at once):
``pump.max_pressure``, ``pump.rise_rate_limit``, ``pump.watchdog_timeout``,
``pump.future_tolerance``, ``pump.accept_unstamped`` (the next PumpRequest obeys them),
``pump.period`` and ``bridge.rate`` (timer periods), ``bridge.publish_on`` (the trigger frame),
``pump.command_source``. Ranges come from the descriptors (ROS refuses an out-of-range value
with a reason); :func:`check_change` refuses inconsistent combinations.

Read-only (descriptor ``read_only``; the description says why): the CAN bus (``can.*``) and
the DBC and signal map (``bridge.dbc_file``, ``map.*``) are opened and checked at configure,
``bridge.publish_raw`` decides at configure whether ``can_frames`` is advertised, the log
input (``input.*``) is chosen at configure, ``autostart`` acts at start only.

Defaults: the pump limits' defaults are :class:`~clutch_ros.canbus.PumpGateConfig`'s (why
those values: its docstring), read from there, never written here again.

Renamed: ``pump.rate_limit`` is now ``pump.rise_rate_limit`` (:data:`RENAMED`), the name of
the same limit in the controller (``controller.rise_rate_limit``); the old name is still
accepted in YAML files, ``-p`` and live sets, with a deprecation warning
(:mod:`clutch_ros.nodes.renamed_params`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from clutch_ros.canbus import PumpGateConfig
from clutch_ros.canbus.pump_gate import PUMP_PERIOD
from clutch_ros.canbus.signal_map import KEYS, SignalMap
from clutch_ros.errors import ClutchError
from clutch_ros.nodes.parameters import DBC_FILE_PARAM, HARDWARE_ID_PARAM, ParamSpec

__all__ = ["GATE_PARAMS", "LIVE", "PARAMS", "RENAMED", "check_change", "gate_config",
           "signal_specs"]

_BUS = "; read-only: the bus is opened at configure (set it at start)"
_DBC = "; read-only: the DBC and signal map are loaded and checked at configure"


def _ro(name, default, description, unit="", minimum=None, maximum=None) -> ParamSpec:
    return ParamSpec(name, default, description, unit, minimum, maximum, read_only=True)


_MAP_DEFAULTS = SignalMap.default_specs()
_GATE = PumpGateConfig()  # the defaults of the pump limits
PARAMS = [
    _ro("autostart", True, "configure and activate at start (false: wait for the lifecycle "
        "services); read-only: acts at start only"),
    _ro("can.interface", "udp_multicast", "python-can interface (socketcan, vector, pcan, "
        "kvaser, udp_multicast, virtual, ...)" + _BUS),
    ParamSpec("can.channel", "239.74.163.2", "interface channel: a name (can0, PCAN_USBBUS1, a "
              "multicast group ...) or a number (Vector, Kvaser: 0)" + _BUS, read_only=True,
              dynamic_typing=True),
    _ro("can.port", 43113, "UDP port (udp_multicast only)" + _BUS, "", 1, 65535),
    _ro("can.bitrate", 0, "bit rate; 0 keeps the interface default" + _BUS, "bit/s", 0,
        20_000_000),
    _ro("can.fd", False, "open the bus in CAN FD mode" + _BUS),
    _ro("can.receive_own_messages", False, "receive frames this node sends" + _BUS),
    _ro("can.filters", [""], "acceptance filters 'ID:MASK[:x]'; empty: all frames" + _BUS),
    DBC_FILE_PARAM,
    ParamSpec("bridge.rate", 200.0, "rig_state publishing rate (at most)", "Hz", 1.0, 5000.0),
    ParamSpec("bridge.publish_on", "input_speed", "DBC message (or signal map key, e.g. "
              "input_speed: its message) whose arrival publishes rig_state; empty: a "
              "bridge.rate timer"),
    _ro("bridge.publish_raw", False, "publish every frame on can_frames; read-only: decides "
        "at configure whether can_frames is advertised"),
    _ro("bridge.compiled", True, "decode, assemble and pace the clean rig frames in compiled "
        "code (numba; the Python path until it is built, and whenever numba is missing, "
        "can_frames is published, or use_sim_time is set); the same rig_state; read-only: "
        "chosen at configure"),
    ParamSpec("pump.max_pressure", _GATE.max_pressure, "largest pressure ever requested",
              "Pa", 1e4, 60e5),
    ParamSpec("pump.rise_rate_limit", _GATE.rate_limit_up, "maximum rise of the requested "
              "pressure; a frame that leaves late rises by at most one pump.period's worth "
              "(formerly pump.rate_limit, still accepted with a warning)", "Pa/s", 1e3, 1e10),
    ParamSpec("pump.watchdog_timeout", _GATE.watchdog_timeout, "no pressure_command for this "
              "long -> 0 bar; more than pump.period", "s", 0.005, 60.0),
    ParamSpec("pump.period", PUMP_PERIOD, "PumpRequest repetition period (the DBC cycle); "
              "less than pump.watchdog_timeout", "s", 0.001, 1.0),
    ParamSpec("pump.future_tolerance", _GATE.future_tolerance, "pressure_command stamped "
              "further ahead of this node's clock than this is refused", "s", 0.0, 10.0),
    ParamSpec("pump.accept_unstamped", _GATE.accept_unstamped, "admit pressure_command "
              "without a stamp"),
    ParamSpec("pump.command_source", "", "admit pressure_command from this node only "
              "(name or fully qualified name); empty: any publisher"),
    _ro("input.log_file", "", "replay this CAN log (.asc, .blf, ...) instead of a bus; "
        "read-only: chosen at configure"),
    _ro("input.realtime", True, "log replay at recorded timing (false: fast); read-only: "
        "chosen at configure"),
    _ro("input.wait_for_subscribers", 0, "log replay starts once rig_state's writer has "
        "matched this many subscriptions; read-only: chosen at configure", "", 0, 1000),
    *(_ro(f"map.{key}", _MAP_DEFAULTS[key], "signal map: 'MESSAGE.SIGNAL [* SCALE] [+ OFFSET]' "
          f"feeding {key} (SI = SCALE * DBC value + OFFSET; no SCALE: by the DBC unit); "
          "empty: not on the bus" + _DBC) for key in KEYS),
    HARDWARE_ID_PARAM,
]

#: parameters of the pump gate (applied with :meth:`PumpCommandGate.reconfigure`)
GATE_PARAMS = ("pump.max_pressure", "pump.rise_rate_limit", "pump.watchdog_timeout",
               "pump.future_tolerance", "pump.accept_unstamped", "pump.period")
#: parameters applied live
LIVE = frozenset(s.name for s in PARAMS if not s.read_only)
#: old parameter name -> its new name (accepted with a deprecation warning)
RENAMED = {"pump.rate_limit": "pump.rise_rate_limit"}


def gate_config(values: Mapping[str, Any]) -> PumpGateConfig:
    """Return the pump gate limits of the parameter values ``values``."""
    return PumpGateConfig(max_pressure=values["pump.max_pressure"],
                          rate_limit_up=values["pump.rise_rate_limit"],
                          watchdog_timeout=values["pump.watchdog_timeout"],
                          future_tolerance=values["pump.future_tolerance"],
                          accept_unstamped=values["pump.accept_unstamped"],
                          max_step_interval=values["pump.period"])


def signal_specs(values: Mapping[str, Any]) -> dict[str, str]:
    """Return the signal map ``{key: spec}`` of the ``map.*`` parameter values."""
    return {key: str(values[f"map.{key}"]) for key in KEYS}


def check_change(values: Mapping[str, Any], dbc_pump_max: float | None) -> str | None:
    """Return why the parameter set ``values`` (current merged with proposed) is refused.

    ``dbc_pump_max`` [Pa]: the DBC maximum of the pump request (None before configure).
    """
    channel = values.get("can.channel", "")
    if isinstance(channel, bool) or not isinstance(channel, str | int):
        return f"can.channel must be a name or a number, got {channel!r}"
    if values["pump.watchdog_timeout"] <= values["pump.period"]:
        return (f"pump.watchdog_timeout ({values['pump.watchdog_timeout']} s) must exceed "
                f"pump.period ({values['pump.period']} s): the watchdog would trip between "
                "two PumpRequests")
    if dbc_pump_max is not None and values["pump.max_pressure"] > dbc_pump_max + 1e-6:
        return (f"pump.max_pressure {values['pump.max_pressure']:.0f} Pa exceeds the DBC "
                f"maximum of the pump request ({dbc_pump_max:.0f} Pa)")
    try:
        gate_config(values)
    except (ClutchError, ValueError) as err:
        return str(err)
    return None
