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
