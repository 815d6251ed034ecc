"""A full bus for a minute: ``python -m benchmarks.can_bridge_node --sustained [--seconds 60]``.

A sender process puts ``--rate`` frames/s (default 8,000, a full 1 Mbit/s classical CAN bus)
on a private ``udp_multicast`` group for ``--seconds``: the rig's own frames exactly as the
simulated rig sends them (:class:`clutch_ros.rig.can_io.RigCanPort`: RigFast and RigSpeed at
1 kHz, PumpStatus, FlexiForce, WheelSpeeds and TorqueRequest at 100 Hz, RigTemperatures at
10 Hz, rolling counters and CRCs), the rest foreign identifiers (11- and 29-bit, random
payloads), paced per millisecond. Two receivers listen to the same datagrams in the same run:

* the ``can_bridge`` node process with the demo's settings (``bridge.rate`` 100 Hz, publishing
  on RigSpeed, the pump gate sending its 0 bar PumpRequests at 100 Hz);
* a bare python-can receive loop in its own process (``recv()`` and count: the floor any
  python-can program pays for this bus), the baseline.

Accounting: frames sent = frames received + frames counted as dropped, per receiver; the
bridge's counts come from its ``/diagnostics`` (``frames_total``; ``receive_drops``: what the
kernel dropped at its socket; ``dropped_frames``: rolling-counter gaps of the rig frames,
which see the same losses from the other side), the bare loop's from its own count and the
kernel's. Latency: each RigState's stamp is its trigger frame's bus time (the kernel's
receive time of the RigSpeed frame); received by an rclpy subscriber in this process, the
difference is trigger-to-publish plus DDS delivery. CPU: utime + stime of each receiver's
process tree from ``/proc/PID/stat``, from the first frame sent until the receiver drained
its backlog, per second of sending [cores]. Everything shares the machine's cores.
``--realtime PRIORITY`` runs the measured path (the bridge, through its ``rt.*`` parameters,
and the receiver) at SCHED_FIFO, as the demo runs its nodes where the OS allows; the sender and
the bare loop, the load, stay at the normal policy.
"""

from __future__ import annotations

import json
import os
import random
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

from can.interfaces.udp_multicast.utils import pack_message

from benchmarks.can_bridge_node import _ROOT, _percentile, _Ros, _say, _stop, private_run
from benchmarks.estimator_node import realtime
from benchmarks.machine_load import process_table
from clutch_ros.canbus.bus import BusConfig, open_bus
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.udp import receive_drops
from clutch_ros.rig.can_io import RigCanPort

__all__ = ["rig_pattern", "run_sustained"]

_PATTERN_MS = 800  # rig frames repeat after 800 ms: 16-step counters of 1 ms/10 ms frames, 10 Hz
_TICK = 0.001  # [s] the sender's pacing step
_PUMP_REQUEST_ID = 0x80  # the bridge's own frames (the bare loop does not count them)


def rig_pattern(ticks: int = _PATTERN_MS) -> list[list[bytes]]:
    """Return the simulated rig's datagrams per 1 ms tick (python-can's udp_multicast form)."""
    port = RigCanPort(SimpleNamespace(), RigDatabase(), start_time=0.0)  # frames_due only
    signals = SimpleNamespace(
        actuating_pressure=20e5, measured_torque=300.0, has_measured_torque=True,
        input_speed=1.05, output_speed=0.0, lamella_temperature=60.0, oil_temperature=50.0,
        ff_voltages=[1.0 + 0.1 * i for i in range(8)], wheel_speeds=[5.0] * 4,
        torque_request=300.0, pump_pressure=20e5, pump_current=1.5)
    return [[pack_message(m) for m in port.frames_due(k * _TICK, signals)]
            for k in range(ticks)]


def _foreign(n: int, seed: int = 7) -> list[bytes]:
    """``n`` foreign frames: identifiers outside the DBC, 11-bit and some 29-bit."""
    import can

    rnd = random.Random(seed)
    out = []
    for i in range(n):
        ext = i % 8 == 7
        ident = (0x18FF0000 | rnd.randrange(0x10000)) if ext else rnd.randrange(0x400, 0x7F0)
        out.append(pack_message(can.Message(arbitration_id=ident, is_extended_id=ext,
                                            data=rnd.randbytes(8))))
    return out


# -- child processes --------------------------------------------------------------------------

def _sender(group: str, port: int, rate: float, seconds: float) -> int:
    """Child: wait for ``go`` on stdin, send for ``seconds``; print one JSON line."""
    pattern, pool = rig_pattern(), _foreign(4096)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", 1))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
    dest, send = (group, port), sock.sendto
    ticks = int(round(seconds / _TICK))
    total = int(round(rate * seconds))
    rig_total = sum(len(pattern[k % _PATTERN_MS]) for k in range(ticks))
    foreign_total = max(0, total - rig_total)
    _say("ready")
    if sys.stdin.readline().strip() != "go":
        return 1
    sent = rig = foreign = failed = 0
    late_max, f = 0.0, 0
    start = time.perf_counter()
    for k in range(ticks):
        delay = start + k * _TICK - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        else:
            late_max = max(late_max, -delay)
        due_foreign = foreign_total * (k + 1) // ticks - foreign_total * k // ticks
        frames = pattern[k % _PATTERN_MS]
        # rig frames first, the foreign ones spread between them
        for i, data in enumerate(frames):
            try:
                send(data, dest)
                sent, rig = sent + 1, rig + 1
            except OSError:
                failed += 1
            for _ in range(due_foreign * (i + 1) // len(frames) - due_foreign * i // len(frames)):
                try:
                    send(pool[f % len(pool)], dest)
                    sent, foreign = sent + 1, foreign + 1
                except OSError:
                    failed += 1
                f += 1
    elapsed = time.perf_counter() - start
    cpu = os.times()
    _say(json.dumps({"sent": sent, "rig": rig, "foreign": foreign, "failed": failed,
                     "seconds": elapsed, "late_max_s": late_max,
                     "cpu_s": cpu.user + cpu.system}))
    sock.close()
    return 0


def _bare(group: str, port: int) -> int:
    """Child: a bare python-can receive loop; counts until ``stop`` on stdin; prints JSON."""
    bus = open_bus(BusConfig(interface="udp_multicast", channel=group, extra={"port": port}))
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.readline(), stop.set()), daemon=True).start()
    received = own = 0
    _say("ready")
    while not stop.is_set():
        msg = bus.recv(0.1)
        if msg is None:
            continue
        if msg.arbitration_id == _PUMP_REQUEST_ID and not msg.is_extended_id:
            own += 1  # the bridge's PumpRequests
        else:
            received += 1
    _say(json.dumps({"received": received, "pump_requests": own,
                     "receive_drops": receive_drops(bus)}))
    bus.shutdown()
    return 0


# -- the parent --------------------------------------------------------------------------------

def _cpu(pid: int) -> float:
    """Utime + stime [s] of ``pid`` and its descendants (0 when gone)."""
    table = process_table()
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        total += table[p][1] if p in table else 0.0
        todo.extend(child for child, (parent, _c) in table.items() if parent == p)
    return total


def _child(args: list[str], env: dict | None = None, log: Path | None = None):
    out = open(log, "w") if log else subprocess.PIPE  # noqa: SIM115 - closed with the process
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.can_bridge_sustained", *args],
                            stdin=subprocess.PIPE, stdout=out, text=True, cwd=_ROOT, env=env,
                            start_new_session=True)
    return proc


def _bridge(group: str, port: int, bridge_rate: float, env: dict, log: Path, priority: int):
    params: dict[str, object] = {"can.interface": "udp_multicast", "can.channel": group,
                                 "can.port": port, "bridge.rate": bridge_rate}
    if priority:  # the node's own rt.* parameters, as the demo sets them
        params.update({"rt.policy": "fifo", "rt.priority": priority, "rt.lock_memory": "true"})
    args = [a for k, v in params.items() for a in ("-p", f"{k}:={v}")]
    with open(log, "w") as out:
        return subprocess.Popen([sys.executable, "-m", "clutch_ros.nodes.can_bridge",
                                 "--ros-args", *args], env=env, stdout=out,
                                stderr=subprocess.STDOUT, cwd=_ROOT, start_new_session=True)


_KEYS = ("frames_total", "receive_drops", "dropped_frames", "decoded_frames", "unknown_frames",
         "decode_errors", "malformed_frames", "own_echoes_dropped", "listener_errors",
         "pump_frames")


def _report_after(ros: _Ros, t: float, timeout: float = 15.0, nth: int = 2) -> dict:
    """Return the bridge's ``nth`` /diagnostics report after monotonic ``t`` (as floats)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        later = [d for when, d in ros.diag if when > t]
        if len(later) >= nth:
            return {k: float(later[nth - 1].get(k, 0.0)) for k in _KEYS}
        time.sleep(0.05)
    raise RuntimeError("no diagnostics from can_bridge")


def _drained(ros: _Ros, t: float, before: dict, sent: int, timeout: float = 60.0) -> dict:
    """Return the first report after ``t`` that accounts for every frame sent.

    Or the first whose frame count did not move since the previous one (backlog read).
    """
    end, nth, last = time.monotonic() + timeout, 2, None
    while time.monotonic() < end:
        report = _report_after(ros, t, nth=nth)
        got = (report["frames_total"] - before["frames_total"]
               + report["receive_drops"] - before["receive_drops"])
        if got >= sent or (last is not None and report["frames_total"] == last):
            return report
        last, nth = report["frames_total"], nth + 1
    raise RuntimeError("can_bridge did not drain its backlog")


def run_sustained(rate: float = 8000.0, seconds: float = 60.0, bridge_rate: float = 100.0,
                  log_dir: Path | None = None, priority: int = 0) -> dict:
    """Run the sustained benchmark; return its figures (see the module docstring).

    ``priority`` > 0: the bridge (its ``rt.*`` parameters) and this process's receiver at
    SCHED_FIFO of that priority with locked memory; the sender and the bare loop stay at the
    normal policy (the load, not the measured path; at the same priority, on 2 cores, the
    sender's bursts had held the bridge off: p99 10.3 ms). This process keeps that policy and
    its locked memory: the command line's process ends with the run.
    """
    group, port, env, log_dir = private_run(log_dir, "clutch_sustained")
    sender = _child(["--sender", group, str(port), str(rate), str(seconds)], env)
    bare = _child(["--bare", group, str(port)], env)
    bridge = _bridge(group, port, bridge_rate, env, log_dir / "can_bridge.log", priority)
    ros = _Ros()
    receiver_policy = realtime(priority)
    try:
        for proc in (sender, bare):
            if proc.stdout.readline().strip() != "ready":
                raise RuntimeError("a benchmark child did not start")
        end = time.monotonic() + 60.0
        while not ros.diag or ros.node.count_publishers("rig_state") == 0:
            if bridge.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"can_bridge did not start (log in {log_dir})")
            time.sleep(0.1)
        before = _report_after(ros, time.monotonic())
        cpu0 = {"bridge": _cpu(bridge.pid), "bare": _cpu(bare.pid)}
        ros.latencies, t0 = [], time.monotonic()
        sender.stdin.write("go\n")
        sender.stdin.flush()
        sent = json.loads(sender.stdout.readline())
        t1 = time.monotonic()
        cpu1 = {"bridge": _cpu(bridge.pid), "bare": _cpu(bare.pid)}
        after = _drained(ros, t1, before, sent["sent"])
        t2 = time.monotonic()
        cpu2 = {"bridge": _cpu(bridge.pid), "bare": _cpu(bare.pid)}
        latencies, ros.latencies = ros.latencies, None
        bare.stdin.write("stop\n")
        bare.stdin.flush()
        bare_out = json.loads(bare.stdout.readline())
    finally:
        _stop(bridge)
        for proc in (sender, bare):
            if proc.poll() is None:
                proc.kill()
        ros.close()
    send_s = t1 - t0

    def cores(name: str) -> dict:
        return {"cores_while_sending": (cpu1[name] - cpu0[name]) / send_s,
                "cores_per_send_second": (cpu2[name] - cpu0[name]) / send_s,
                "cpu_us_per_frame": (cpu2[name] - cpu0[name]) / sent["sent"] * 1e6}

    d = {k: after[k] - before.get(k, 0.0) for k in after}
    # the kernel's count includes echoes of the bridge's own PumpRequests (sent, not removed)
    own_lost = max(0, int(d["pump_frames"] - d["own_echoes_dropped"]))
    bridge_res = {"received": int(d["frames_total"]),
                  "kernel_drops": int(d["receive_drops"]) - own_lost, "own_echoes_lost": own_lost,
                  "counter_drops": int(d["dropped_frames"]), "decoded": int(d["decoded_frames"]),
                  "unknown": int(d["unknown_frames"]), "decode_errors": int(d["decode_errors"]),
                  "malformed": int(d["malformed_frames"]),
                  "listener_errors": int(d["listener_errors"]), **cores("bridge")}
    bare_res = {"received": bare_out["received"], "kernel_drops": bare_out["receive_drops"] or 0,
                **cores("bare")}
    for r in (bridge_res, bare_res):
        r["unaccounted"] = sent["sent"] - r["received"] - r["kernel_drops"]
    return {"bus": f"udp_multicast {group}:{port}", "rate_target": rate, "seconds": seconds,
            "bridge_rate": bridge_rate, "realtime": receiver_policy, "sender": sent,
            "drain_s": t2 - t1,
            "bridge": bridge_res, "bare": bare_res,
            "latency": {"samples": len(latencies),
                        "median_ms": statistics.median(latencies) * 1e3 if latencies else None,
                        "p99_ms": _percentile(latencies, 0.99) * 1e3,
                        "max_ms": max(latencies) * 1e3 if latencies else None}}


def print_table(r: dict) -> None:
    """Print the figures of :func:`run_sustained` as a table."""
    s = r["sender"]
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    _say(f"can_bridge under a full bus: {r['bus']}, {s['sent']} frames in {s['seconds']:.1f} s "
         f"= {s['sent'] / s['seconds']:.0f} frames/s ({s['rig']} rig, {s['foreign']} foreign; "
         f"{s['failed']} send failures, sender late by up to {s['late_max_s'] * 1e3:.1f} ms), "
         f"bridge.rate {r['bridge_rate']:.0f} Hz, {os.cpu_count()} CPUs shared "
         f"(load {load}); scheduling: {r['realtime']}")
    _say(f"{'receiver':<30} {'received':>9} {'kernel drops':>12} {'unaccounted':>11} "
         f"{'cores':>6} {'us/frame':>8}")
    for name, key in (("can_bridge node", "bridge"), ("bare python-can recv loop", "bare")):
        x = r[key]
        _say(f"{name:<30} {x['received']:>9} {x['kernel_drops']:>12} {x['unaccounted']:>11} "
             f"{x['cores_per_send_second']:>6.3f} {x['cpu_us_per_frame']:>8.1f}")
    b, lat = r["bridge"], r["latency"]
    _say(f"bridge: decoded {b['decoded']}, unknown {b['unknown']}, decode errors "
         f"{b['decode_errors']}, malformed {b['malformed']}, rolling-counter drops "
         f"{b['counter_drops']}, listener errors {b['listener_errors']}; drained "
         f"{r['drain_s']:.1f} s after the last frame")
    if lat["samples"]:
        _say(f"rig_state trigger frame -> received: median {lat['median_ms']:.3f} ms, p99 "
             f"{lat['p99_ms']:.3f} ms, max {lat['max_ms']:.3f} ms (n={lat['samples']})")


def main(argv: list[str] | None = None) -> int:
    """Run the sustained mode's command line (and its child processes)."""
    import argparse

    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--sender"]:
        return _sender(argv[1], int(argv[2]), float(argv[3]), float(argv[4]))
    if argv[:1] == ["--bare"]:
        return _bare(argv[1], int(argv[2]))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sustained", action="store_true", help="(this mode)")
    parser.add_argument("--seconds", type=float, default=60.0, help="sending time [s]")
    parser.add_argument("--rate", type=float, default=8000.0,
                        help="frames/s in total, rig frames plus foreign ones (at least the "
                        "rig's ~2,510)")
    parser.add_argument("--bridge-rate", type=float, default=100.0,
                        help="bridge.rate [Hz] (the demo's 100)")
    parser.add_argument("--realtime", type=int, default=0, metavar="PRIORITY",
                        help="run the bridge (its rt.* parameters) and the rig_state receiver at "
                        "SCHED_FIFO of this priority with locked memory, as the demo runs its "
                        "nodes where the OS allows; the sender and the bare loop stay at the "
                        "normal policy (default 0: everything at the normal policy)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    if not 0 <= args.realtime <= 99:
        parser.error(f"--realtime: a priority 1..99 (or 0 for off), got {args.realtime}")
    result = run_sustained(args.rate, args.seconds, args.bridge_rate, priority=args.realtime)
    if args.json:
        _say(json.dumps(result, indent=2))
    else:
        print_table(result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
