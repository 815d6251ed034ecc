"""The --jobs benchmark runs end to end on small generated bags, every baseline included."""

import json

from benchmarks import batch_replay as bench


def test_parallel_serial_and_one_core_replays_agree(capsys):
    assert bench.main(["--count", "2", "--seconds", "2", "--repeat", "1", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["bags"] == 2 and doc["samples"] == 4000 and doc["jobs"] == 2
    assert doc["identical"] is True  # serial, --no-stream and --jobs: the same figures
    for key in ("serial_wall_s", "one_core_wall_s", "startup_wall_s", "parallel_wall_s"):
        assert doc[key] > 0.0, key
    # the --jobs run's CPU, split into the parent's and each worker's (sampled from /proc)
    assert len(doc["parallel_worker_cpu_s"]) == 2
    assert all(w > 0.0 for w in doc["parallel_worker_cpu_s"])
    assert doc["parallel_parent_cpu_s"] > 0.0
    assert doc["parallel_total_cpu_s"] >= sum(doc["parallel_worker_cpu_s"])
    assert doc["critical_path_cpu_s"] <= doc["parallel_total_cpu_s"]
    assert doc["one_core_cpu_s"] > 0.0
