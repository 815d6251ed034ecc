"""The live CPU benchmark runs the quick demo with its echo baseline (no timing assertions)."""

import json
import math
import os

from benchmarks import live_cpu as bench


def test_read_cpu_of_this_process_and_of_none():
    assert bench.read_cpu(os.getpid()) >= 0.0
    assert bench.read_cpu(2**22 + 12345) is None  # beyond pid_max: no such process


def test_bench_prints_every_node_per_second_and_per_message(capsys, tmp_path):
    """With the chain's skeleton beside it (--skeleton, benchmarks/chain_skeleton.py)."""
    assert bench.main(["--quick", "--json", "--skeleton", "--keep", str(tmp_path / "run")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["nodes"]) == {*bench.NODES, bench.ECHO, *bench.SKELETON}
    floor = sum(res["nodes"][n]["cpu_core"] for n in bench.SKELETON)
    assert math.isclose(res["skeleton_core"], floor)
    assert res["nodes"]["skeleton bridge"]["topic"] == "/skeleton/rig_state"
    assert res["rig_time_s"] > 10.0  # the quick profile's driven part
    for name, node in res["nodes"].items():
        assert node["messages"] > 0, name
        for key in ("cpu_s", "cpu_core", "cpu_per_message_ms"):
            assert math.isfinite(node[key]) and node[key] > 0.0, (name, key, node)
    chain = sum(res["nodes"][n]["cpu_core"] for n in bench.CHAIN)
    assert math.isclose(res["chain_core"], chain)
    assert res["within_budget"] == (chain <= res["budget_core"])
    assert (tmp_path / "run" / "bag").is_dir()  # --keep keeps the demo's run directory
    machine = res["machine"]  # what else ran on the machine (benchmarks/machine_load.py)
    assert set(machine) == {"busy_core", "outside_core", "steal_core"}
    assert 0.0 <= machine["outside_core"] <= machine["busy_core"] <= os.cpu_count() + 0.05
    assert machine["busy_core"] >= chain - 0.05  # the chain ran on this machine, in the window


def test_bench_one_process_measures_the_chain_as_one_process(capsys, tmp_path):
    """--one-process: the demo runs bridge, estimator and controller as one process."""
    assert bench.main(["--quick", "--json", "--one-process", "--keep", str(tmp_path / "r")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["nodes"]) == {*bench.ONE_PROCESS_NODES, bench.ECHO}
    assert res["skeleton_core"] is None  # (not asked for)
    composed = res["nodes"]["composed"]
    assert composed["messages"] > 0 and composed["cpu_core"] > 0.0
    assert math.isclose(res["chain_core"], composed["cpu_core"])
    assert res["demo"]["within_10pct"] > 0.0  # the composed chain controlled the rig
    logs = {p.name for p in (tmp_path / "r" / "logs").glob("*.log")}
    assert "chain.log" in logs and "estimator.log" not in logs, logs
