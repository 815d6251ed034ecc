"""The can_bridge node's health as a diagnostic status.

:func:`bridge_status` returns (level, message, key/values). Levels: ERROR when the CAN
link is down; WARN when no rig frame arrived since the previous report, required signal
groups are stale, frames were dropped, decode or error frames were seen since the previous
report, another node sent PumpRequest frames (the bridge's own echo is removed by the bus,
so any PumpRequest received means a second master on the pump), malformed datagrams were
dropped, pressure commands were refused (stale, future, out of order, unstamped, foreign
source), or the pump watchdog tripped; ERROR as well when more than one node publishes
``pressure_command``. OK otherwise. Counts are totals since start; rates are per second
since the previous report.

Size: the values are bounded whatever the bus carries (per-identifier rates for the DBC's
frames only, the ten most frequent unknown identifiers in one value with the rest summed,
reasons from fixed sets); :data:`MAX_VALUES` is a last guard.
"""

from __future__ import annotations

import time

__all__ = ["MAX_VALUES", "bridge_status"]

#: Most key/values one status carries (a guard; the values are bounded by construction).
MAX_VALUES = 200

_previous: dict[int, dict] = {}


def bridge_status(assembler, bus, gate, rig_keys, extra: dict):
    """Return ``(level, message, values)`` for the bridge's /diagnostics status.

    ``rig_keys``: frame keys of the rig's signal groups; ``extra``: node values added as
    they are, among them ``stale_groups`` (groups stale in the last published sample) and
    ``foreign_pump_requests`` (PumpRequest data frames received).
    """
    c = assembler.counters()
    total_rate, per_id = assembler.rates(time.monotonic())
    prev = _previous.setdefault(id(assembler), {})
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
                      ("pump_refused_commands", "refused pressure commands"),
                      ("dropped_frames", "dropped frames"), ("watchdog_trips", "watchdog trips"),
                      ("foreign_pump_requests", "PumpRequest frames from another node")):
        new = values.get(key, 0) - prev.get(key, 0)
        if new > 0:
            problems.append(f"{new} new {what}")
            level = "WARN" if level == "OK" else level
        prev[key] = values.get(key, 0)
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
