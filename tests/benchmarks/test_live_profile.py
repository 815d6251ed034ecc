"""The live profile benchmark runs the quick demo with one node hooked (no timing assertions)."""

import json

import pytest

from benchmarks import live_profile as bench


def test_profiles_the_estimators_hot_paths_over_the_driven_demo(capsys):
    assert bench.main(["estimator", "--quick", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["node"] == "estimator" and not res["errors"]
    assert set(res["targets"]) == set(bench.DEFAULT_TARGETS["estimator"])
    window = res["window_s"]
    assert window > 10.0  # the quick profile's driven part
    estimate = res["targets"]["clutch_ros.nodes.estimator:EstimatorNode._estimate"]
    update = res["targets"]["clutch_ros.model.adaptation:AdaptiveEstimator.update"]
    step = res["targets"]["clutch_ros.model.pack:PackModel.step"]
    # one estimate per rig_state (~100 /s): each runs the model once, inside it
    assert 50.0 < estimate["calls"] / window < 200.0
    assert abs(update["calls"] - estimate["calls"]) <= 1 and step["calls"] >= update["calls"]
    assert 0.0 < step["cpu_s"] <= update["cpu_s"] <= estimate["cpu_s"] * 1.01
    threads = res["threads_cpu_s"]
    assert threads["MainThread"] >= estimate["cpu_s"] - 0.05  # (/proc: 10 ms ticks)
    assert res["process_cpu_s"] >= sum(threads.values()) - 0.05
    assert set(res["machine"]) == {"busy", "outside", "steal"}


def test_a_malformed_target_stops_before_the_demo(capsys):
    with pytest.raises(SystemExit) as stop:
        bench.main(["can_bridge", "clutch_ros.canbus.bus"])
    assert stop.value.code == 2
    assert "expected module:Class.method" in capsys.readouterr().err
