"""The benchmark runs and prints one line per law (no timing assertions)."""

from benchmarks import model_step as bench


def test_bench_prints_every_law(capsys):
    assert bench.main(["--repeat", "1", "--step-samples", "200", "--dt", "0.01"]) == 0
    out = capsys.readouterr().out
    for law in bench.LAWS:
        line = next(x for x in out.splitlines() if x.startswith(law + " "))
        assert len(line.split()) == 5  # law, us/step, xRT, samples/s, xRT
    assert "targets" in out
