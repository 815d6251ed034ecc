"""The benchmark runs and prints one line per law (no timing assertions)."""

from benchmarks import model_step as bench


def test_bench_prints_every_law(capsys):
    assert bench.main(["--repeat", "1", "--step-samples", "200", "--dt", "0.01"]) == 0
    out = capsys.readouterr().out
    for law in bench.LAWS:
        line = next(x for x in out.splitlines() if x.startswith(law + " "))
        # law | step() us, xRT | simulate numpy us, xRT | simulate kernel us, xRT | speed-up
        # | the kernel one sample per call [us] (none for the printed laws: no output loop)
        cells = [c.split() for c in line.split("|")]
        assert [len(c) for c in cells] == [3, 2, 2, 1, 1], line
        single = float(cells[4][0])
        assert single != single if law.endswith("_printed") else single > 0.0, line
        for value in (*cells[0][1:], *cells[1], *cells[2]):
            assert float(value) > 0.0, line
        assert cells[3][0].endswith("x") and float(cells[3][0][:-1]) > 0.0, line
    assert "targets" in out
