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
