"""The benchmark runs end to end (figures are printed, never asserted on timing)."""

from benchmarks import can_decode as bench


def test_bench_smoke(capsys):
    results = bench.run_bench(frames=500, seconds=0.05)
    assert [r.path.split()[0] for r in results] == ["bare", "Notifier"]
    for r in results:
        assert r.lost == 0
        assert r.throughput > 0
        assert r.lat_p99_1k >= r.lat_median_1k >= 0
    assert bench.main(["--frames", "200", "--seconds", "0.02", "--json"]) == 0
    assert '"throughput"' in capsys.readouterr().out
