"""The whole-process replay benchmark runs end to end on a small generated bag."""

import json

from benchmarks import replay_process as bench


def test_every_row_is_a_real_replay_of_the_whole_bag(capsys):
    assert bench.main(["--seconds", "3", "--laws", "ff_t", "--repeat", "1", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["samples"] == 3000 and doc["realtime_s"] == 3.0
    assert set(doc["first_run_s"]) == {"ff_t"} and doc["first_run_s"]["ff_t"] > 0.0
    assert set(doc["replay"]) == {"ff_t", "ff_t --no-stream"}
    assert doc["replay"]["ff_t --no-stream"]["streamed"] is False
    for row in (doc["startup"], doc["read_only"], *doc["replay"].values()):
        assert row["wall_s"] > 0.0 and row["cpu_s"] > 0.0
