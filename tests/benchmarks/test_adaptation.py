"""The adaptation benchmark runs and prints its baseline and both variants (no timing asserts)."""

from benchmarks import adaptation as bench


def test_bench_prints_baseline_and_variants(capsys):
    assert bench.main(["--repeat", "1", "--samples", "300"]) == 0
    rows = capsys.readouterr().out.splitlines()[1:]
    assert [r.split("  ")[0] for r in rows] == [
        "ClutchEstimator (baseline)", "AdaptiveEstimator, scale",
        "AdaptiveEstimator, scale + gain"]
    assert rows[0].split()[-2] == "1.00"  # the baseline's ratio to itself
