"""The benchmark runs end to end on a small generated bag and reports sensible figures."""

import json

import numpy as np

from benchmarks import bag_replay as bench
from clutch_ros.bag.rig_states import read_rig_states


def test_generated_bag_holds_the_synthetic_run(tmp_path):
    path = tmp_path / "gen"
    assert bench.generate_bag(path, seconds=1.5, rate_hz=1000) == 1500
    a = read_rig_states(path)
    assert len(a) == 1500
    assert a.stamp_ns[0] == bench.START_NS and np.all(np.diff(a.stamp_ns) == 1_000_000)
    assert np.all(a.bag_time_ns == a.stamp_ns)
    assert 0 <= a.actuating_pressure.min() and a.actuating_pressure.max() < 45e5
    assert np.allclose(a.slip_speed[:10], 10 * 2 * np.pi / 60)
    assert a.ff_voltages.shape == (1500, 8) and a.has_measured_torque.all()


def test_bench_prints_samples_per_second(capsys):
    assert bench.main(["--seconds", "2"]) == 0
    out = capsys.readouterr().out
    assert "2000 RigState messages" in out
    for label in (
        "bare rosbags read+deserialize",
        "read_rig_states (numpy)",
        "offline replay (flexiforce_8)",
    ):
        line = next(x for x in out.splitlines() if x.startswith(label))
        rate, _, realtime, _, _, vs_bare, _ = line[len(label) :].split()
        # a figure, not a timed assertion (the first replay may pay the kernel's compilation)
        assert float(rate.replace(",", "")) > 0.0
        # printed as whole multiples of real time: a cold kernel cache can print 0x
        assert float(realtime.replace(",", "").rstrip("x")) >= 0.0 and float(vs_bare[:-1]) >= 0
    assert "of which read_rig_states" in out and "estimate_batch" in out
    assert "replay targets: >= 100x real time" in out
    assert bench.main(["--seconds", "1", "--storage", "sqlite3", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["samples"] == 1000 and res["storage"] == "sqlite3"
    assert res["read_rig_states_per_s"] > 0 and res["bare_rosbags_per_s"] > 0
    assert res["replay_per_s"] > 0 and res["replay_preset"] == "flexiforce_8"
    assert res["replay_realtime"] == res["replay_per_s"] / 1000.0
    assert res["replay_vs_bare"] == res["replay_per_s"] / res["bare_rosbags_per_s"]
    assert res["replay_read_s"] > 0 and res["replay_estimate_s"] > 0
    assert bench.main(["--seconds", "1", "--no-replay", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["replay_per_s"] is None
