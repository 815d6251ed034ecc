"""The node benchmark runs end to end against a real can_bridge process (figures not asserted)."""

import pytest

from benchmarks import can_bridge_node as node_bench

pytestmark = pytest.mark.ros


def test_node_bench_smoke(tmp_path, capsys, ros_env):
    bus, results = node_bench.run(rates=(1000,), step_s=0.5, lat_s=0.5, modes=("trigger",),
                                  log_dir=tmp_path)
    assert bus.startswith("udp_multicast 239.")
    assert [r.name.split(",")[0] for r in results] == ["bare python-can recv loop",
                                                       "can_bridge node"]
    for r in results:
        assert len(r.steps) == 1 and r.steps[0].sent == 500
        assert r.steps[0].lossless, r.steps  # 1,000 frames/s: far below either limit
        assert r.latency_samples > 100
        assert 0.0 <= r.latency_median_ms <= r.latency_p99_ms


def test_rig_pattern_is_the_simulated_rigs_frames():
    from benchmarks.can_bridge_sustained import rig_pattern

    pattern = rig_pattern()
    assert len(pattern) == 800 and all(len(tick) >= 2 for tick in pattern)  # RigFast, RigSpeed
    assert sum(map(len, pattern)) == 800 * 2 + 80 * 5 + 8  # 1 kHz x2, 100 Hz x5, 10 Hz


def test_sustained_mode_accounts_for_every_frame(tmp_path, capsys, ros_env):
    from benchmarks.can_bridge_sustained import print_table, run_sustained

    result = run_sustained(rate=3000.0, seconds=2.0, log_dir=tmp_path)
    sent = result["sender"]
    # 2 s of the rig: RigFast + RigSpeed 2,000 each, five 100 Hz frames, RigTemperatures 20
    assert sent["sent"] == 6000 and sent["failed"] == 0 and sent["rig"] == 5020
    for name in ("bridge", "bare"):
        r = result[name]
        assert r["received"] + r["kernel_drops"] == sent["sent"], (name, r)
        assert r["cores_per_send_second"] > 0.0
    b = result["bridge"]
    assert b["decoded"] + b["unknown"] + b["decode_errors"] == b["received"]
    assert b["malformed"] == b["decode_errors"] == b["listener_errors"] == 0
    if b["kernel_drops"] == 0:  # (a stalled machine may make the kernel drop some)
        assert (b["decoded"], b["unknown"]) == (sent["rig"], sent["foreign"])
    assert result["latency"]["samples"] > 50
    print_table(result)
    assert "can_bridge node" in capsys.readouterr().out


def test_sustained_realtime_option_reports_what_the_os_did(tmp_path, ros_env):
    """``--realtime``: the bridge and the receiver ask for SCHED_FIFO and the run says the outcome.

    Applied or refused (a machine may refuse it), the run goes on and reports which.
    """
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "benchmarks.can_bridge_node", "--sustained",
                          "--seconds", "1", "--rate", "3000", "--realtime", "10", "--json"],
                         capture_output=True, text=True, timeout=180, check=True)
    result = json.loads(out.stdout)
    assert result["realtime"].startswith(("real-time options applied: SCHED_FIFO priority 10",
                                          "real-time options refused: SCHED_FIFO priority 10"))
    assert result["bridge"]["received"] + result["bridge"]["kernel_drops"] == 3000
    bad = subprocess.run([sys.executable, "-m", "benchmarks.can_bridge_node", "--sustained",
                          "--realtime", "100"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "a priority 1..99" in bad.stderr
