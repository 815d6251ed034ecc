"""The can_bridge node's health as a diagnostic status.

:func:`bridge_status` returns (level, message, key/values). Levels: ERROR when the CAN
link is down; WARN when no rig frame arrived since the previous report, required signal
groups are stale, frames were dropped (a rolling-counter gap, or ``receive_drops``: frames
the OS dropped before this node read them, counted by the kernel for udp_multicast), decode
or error frames were seen since the previous
report, another node sent PumpRequest frames (the bridge's own echo is removed by the bus,
so any PumpRequest received means a second master on the pump), malformed datagrams were
dropped, pressure commands were refused (stale, future, out of order, unstamped, foreign
source), the pump watchdog tripped, or a rig_state went out more than :data:`LAG_WARN` after
its newest frame (``receive_lag_max_s``, the largest since the previous report); ERROR as
well when more than one node publishes ``pressure_command``. OK otherwise. Counts are totals
since start; rates are per second since the previous report.

Size: the values are bounded whatever the bus carries (per-identifier rates for the DBC's
frames only, the ten most frequent unknown identifiers in one value with the rest summed,
reasons from fixed sets); :data:`MAX_VALUES` is a last guard.

Everything comes from the node's :class:`~clutch_ros.nodes.can_bridge_state.BridgeState`
(its public fields); the counts of the previous report, against which "new" is judged, are
kept there too (``reported``), so they start again at configure and go with the node.
"""

from __future__ import annotations

import time
from typing import Any

from clutch_ros.nodes.can_bridge_state import BridgeState
from clutch_ros.nodes.controller_params import RIG_TIMEOUT

__all__ = ["MAX_VALUES", "SOFTWARE_BUSES", "bridge_status", "hardware_id", "node_status"]

#: python-can interfaces without hardware: here they carry the simulated rig (rig_sim)
SOFTWARE_BUSES = ("udp_multicast", "virtual")


def hardware_id(params) -> str:
    """Return the bridge's diagnostics ``hardware_id`` from its parameters.

    ``interface:channel`` (``socketcan:can0``); ``simulated rig (interface:channel)`` on a
    software bus (:data:`SOFTWARE_BUSES`, where ``rig_sim`` speaks, the same id it reports);
    ``log:PATH`` when replaying ``input.log_file``.
    """
    if params.get("input.log_file"):
        return f"log:{params['input.log_file']}"
    bus = f"{params['can.interface']}:{params['can.channel']}"
    return f"simulated rig ({bus})" if params["can.interface"] in SOFTWARE_BUSES else bus

#: [s] a rig_state published this long after its newest frame makes the status WARN: the
#: controller's default ``controller.rig_timeout`` (0.25 s), when data that late is refused.
LAG_WARN = RIG_TIMEOUT
#: Most key/values one status carries (a guard; the values are bounded by construction).
MAX_VALUES = 200


def bridge_status(state: BridgeState,
                  extra: dict[str, Any]) -> tuple[str, str, dict[str, Any]]:
    """Return ``(level, message, values)`` for the bridge's /diagnostics status.

    ``state``: a configured bridge's state (assembler, gate, bus, pacer; its ``reported``
    counts are updated); ``extra``: node values added as they are, among them
    ``stale_groups`` (groups stale in the last published sample) and
    ``foreign_pump_requests`` (PumpRequest data frames received).
    """
    assembler, bus, gate, prev = state.assembler, state.bus, state.gate, state.reported
    assert assembler is not None and gate is not None and state.pacer is not None  # configured
    rig_keys = state.pacer.fallback  # frame keys of the rig's signal groups
    c = assembler.counters()
    total_rate, per_id = assembler.rates(time.monotonic())
    values = {
        "frames_total": c.frames_total, "frame_rate_hz": total_rate,
        "rig_frame_rate_hz": sum(r for k, r in per_id.items() if k in rig_keys),
        "decoded_frames": c.decoded_frames, "unknown_frames": c.unknown_frames,
        "unknown_ids": c.unknown_ids_text(), "decode_errors": c.decode_errors,
        "error_frames": c.error_frames, "bus_off_frames": c.bus_off_frames,
        "remote_frames": c.remote_frames, "fd_frames": c.fd_frames,
        "dropped_frames": c.dropped_frames, "counter_repeats": c.counter_repeats,
        "listener_errors": c.listener_errors,
        "unknown_frames_untracked": c.unknown_untracked,
        "pump_request_pa": gate.applied_pressure, "pump_frames": gate.frames,
        "pump_immediate_frames": gate.immediate_frames,
        "pump_commands": gate.commands, "pump_rejected_commands": gate.rejected_commands,
        "pump_refused_commands": sum(gate.refused.values()),
        "pump_last_refusal": gate.last_refusal,
        "watchdog_trips": gate.watchdog_trips, **extra,
    }
    values.update({f"pump_refused_{k}": n for k, n in sorted(gate.refused.items())})
    values.update({f"decode_errors_{k}": n for k, n in sorted(c.decode_errors_by_reason.items())})
    values.update({f"rate_0x{key:X}_hz": rate for key, rate in sorted(per_id.items())})
    level, problems = "OK", []
    if bus is not None:
        status = bus.status()
        values.update({"link_state": str(status.state), "link_reason": status.reason,
                       "bus_state": status.bus_state, "connects": status.connects,
                       "disconnects": status.disconnects, "send_failures": status.send_failures,
                       "own_echoes_dropped": status.own_echoes,
                       "malformed_frames": status.malformed_frames})
        if status.receive_drops is not None:  # the OS's own count (udp_multicast on Linux)
            values["receive_drops"] = status.receive_drops
        values.update({f"malformed_{k}": n
                       for k, n in sorted((status.malformed_by_reason or {}).items())})
        if str(status.state) != "up":
            level = "ERROR"
            problems.append(f"CAN link {status.state}: {status.reason}")
    publishers = extra.get("command_publisher_count", 0)
    if publishers > 1:
        level = "ERROR"
        problems.append(f"{publishers} publishers on pressure_command: "
                        f"{extra.get('command_publishers', '')}")
    for key, what in (("decode_errors", "decode errors"), ("error_frames", "error frames"),
                      ("malformed_frames", "malformed frames dropped"),
                      ("receive_drops", "frames dropped by the OS before this node read them"),
                      ("pump_refused_commands", "refused pressure commands"),
                      ("dropped_frames", "dropped frames"), ("watchdog_trips", "watchdog trips"),
                      ("foreign_pump_requests", "PumpRequest frames from another node")):
        new = values.get(key, 0) - prev.get(key, 0)
        if new > 0:
            problems.append(f"{new} new {what}")
            level = "WARN" if level == "OK" else level
        prev[key] = values.get(key, 0)
    if extra.get("receive_lag_max_s", 0.0) > LAG_WARN:
        problems.append(f"published up to {extra['receive_lag_max_s']:.3f} s after the bus "
                        "(this node runs late)")
        level = "WARN" if level == "OK" else level
    if extra.get("stale_groups"):
        problems.append(f"stale: {extra['stale_groups']}")
        level = "WARN" if level == "OK" else level
    if values["rig_frame_rate_hz"] == 0.0 and level == "OK":
        level = "WARN"
        problems.append("no rig frames")
    if len(values) > MAX_VALUES:  # cannot happen with the bounded counters; stay bounded
        kept = dict(list(values.items())[:MAX_VALUES - 1])
        kept["values_truncated"] = len(values) - len(kept)
        values = kept
    return level, "; ".join(problems) or "bridging", values


def node_status(state: BridgeState, logger, idle_timeout: float):
    """Return the /diagnostics ``(level, message, values)`` of a can_bridge's ``state``.

    Unconfigured: its lifecycle state only. Otherwise :func:`bridge_status` with the node's
    own values (lifecycle state, rig_state published, stale groups, the largest publishing lag
    since the previous report [s], the frames taken by the compiled intake (0: all in Python),
    command publishers or the log replay); the message starts
    with the state unless active. An idle bus (no new rig frame for ``idle_timeout`` [s]) while
    active logs one warning on ``logger``, and one line when frames come back.
    """
    lifecycle = state.lifecycle
    if state.assembler is None:
        return "OK", lifecycle, {"lifecycle_state": lifecycle}
    if state.bus is not None and state.active:
        idle = time.monotonic() - state.last_new
        if idle > idle_timeout and not state.idle_warned:
            state.idle_warned = True
            logger.warning(f"no new rig frames for {idle:.1f} s; rig_state paused")
        elif idle <= idle_timeout and state.idle_warned:
            state.idle_warned = False
            logger.info("rig frames again; rig_state resumed")
    extra = {"lifecycle_state": lifecycle, "rig_state_published": state.published,
             "stale_samples": state.stale_samples,
             "stale_groups": ", ".join(state.stale_groups or []),
             "receive_lag_max_s": state.lag_max,
             "foreign_pump_requests": state.foreign_pump_requests,
             "frames_compiled": state.intake.taken if state.intake is not None else 0}
    source, thread = state.source, state.log_thread
    if source is None:
        extra.update(state.sources.diagnose())
    else:
        extra.update(log_file=str(source.path), log_frames=source.frames_read,
                     log_done=thread is not None and not thread.is_alive())
    state.lag_max = 0.0  # the next report covers the next period
    level, message, values = bridge_status(state, extra)
    return level, (message if state.active else f"{lifecycle}; {message}"), values
