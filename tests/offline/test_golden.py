"""Regression suite: every golden bag through ``clutch replay`` gives the stored outputs.

The golden bags (``tests/data/golden``, made by ``tools/make_golden.py``; see its README) are
simulated Table 3/4 runs. Each is replayed with the ``clutch replay ... -o OUT --json`` code
path (in process) and the ClutchEstimate bag it writes is compared with the stored
per-sample outputs and summary figures within ``clutch_ros.offline.golden.TOLERANCES``:

- torques: rtol 1e-7, atol 1e-4 N m; P_diff: rtol 1e-7, atol 1e-2 Pa (per sample);
- RMSEs rtol 1e-7, accuracy extremes rtol 1e-6, within_10pct +- one counted sample.

A failure prints, per output, how many samples moved, the largest deviation and where (sample
index and time), and the first one. If the change is deliberate, regenerate (README).
"""

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from clutch_ros.bag.arrays import read_columns
from clutch_ros.cli import main as clutch
from clutch_ros.config.params_file import load_flat, load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.offline import golden
from clutch_ros.offline.rig_runs import GOLDEN_RUNS
from tests.conftest import REPO

ROOT = REPO / "tests" / "data" / "golden"
RUNS = sorted(GOLDEN_RUNS)
HINT = (
    "\nIf this change of the estimator's results is deliberate, regenerate the golden outputs: "
    ".venv/bin/python tools/make_golden.py --expected (tests/data/golden/README.md)"
)


@pytest.fixture(scope="module")
def manifest():
    return golden.load_manifest(ROOT)


def test_golden_set_is_complete_small_and_made_with_the_current_preset(manifest):
    assert sorted(manifest["runs"]) == RUNS
    for run in RUNS:
        assert golden.bag_path(ROOT, run).is_dir() and golden.expected_path(ROOT, run).is_file()
    total = sum(f.stat().st_size for f in ROOT.rglob("*") if f.is_file())
    assert total < 3.2e6, f"golden data grew to {total / 1e6:.2f} MB"
    current = load_flat(preset_path(golden.PRESET))
    changed = {
        k: (manifest["params"].get(k), current.get(k))
        for k in set(current) | set(manifest["params"])
        if manifest["params"].get(k) != current.get(k)
    }
    assert not changed, f"params/{golden.PRESET}.yaml changed since the golden outputs were " \
        f"made (stored, now): {changed}{HINT}"  # fmt: skip


@pytest.mark.parametrize("run", RUNS)
def test_replay_matches_the_golden_outputs(run, manifest, tmp_path, capsys):
    bag = golden.bag_path(ROOT, run)
    out = tmp_path / "estimates"
    code = clutch(["replay", str(bag), "--params", golden.PRESET, "-o", str(out), "--json"])
    assert code == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)[0]
    cols, bag_ns, strings = read_columns(out, "/clutch_estimate")
    expected = golden.load_expected(ROOT, run)

    # one estimate per input sample, stamped with the input's stamp (exact)
    assert np.array_equal(cols["stamp_ns"], expected["stamp_ns"]), (
        f"{run}: {len(cols['stamp_ns'])} estimates, expected {len(expected['stamp_ns'])} "
        "with the golden stamps"
    )
    assert np.array_equal(bag_ns, cols["stamp_ns"])
    assert strings == {"header.frame_id": "rig", "spline_law": "ff_t"}
    assert summary["estimates_written"] == summary["accepted"] == len(expected["stamp_ns"])

    t = (expected["stamp_ns"] - expected["stamp_ns"][0]) / 1e9
    problems = [
        diff
        for field in golden.FIELDS
        if (diff := golden.compare_series(run, field, expected[field], cols[field], t))
    ]
    problems += golden.compare_summary(run, manifest["runs"][run], summary)
    for field in golden.FIELDS:
        rtol, atol, _ = golden.TOLERANCES[field]  # torques 1e-7 / 1e-4 N m, P_diff 1e-7 / 1e-2 Pa
        np.testing.assert_allclose(
            cols[field], expected[field], rtol=rtol, atol=atol, err_msg="\n".join(problems) + HINT
        )
    assert not problems, "\n".join(problems) + HINT


def test_a_model_change_fails_with_a_readable_diff(manifest):
    """The comparison can fail: 0.2 % more friction moves every torque and says where."""
    run = "table3_seq1_10rpm"
    params = load_params(preset_path(golden.PRESET))
    changed = params.replace(**{"friction.mu_ref": params.friction.mu_ref * 1.002})
    arrays, summary = golden.compute_expected(golden.bag_path(ROOT, run), changed)
    expected = golden.load_expected(ROOT, run)
    t = (expected["stamp_ns"] - expected["stamp_ns"][0]) / 1e9
    diff = golden.compare_series(
        run, "modelled_torque", expected["modelled_torque"], arrays["modelled_torque"], t
    )
    assert diff is not None
    assert diff.startswith(f"{run} modelled_torque: ") and "max |deviation|" in diff
    assert "at sample" in diff and "(t = " in diff and "expected" in diff and "got" in diff
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(
            arrays["modelled_torque"], expected["modelled_torque"], rtol=1e-7, atol=1e-4
        )
    assert any("rmse_nm" in line for line in golden.compare_summary(run, manifest["runs"][run],
                                                                     summary))  # fmt: skip
    # unchanged parameters reproduce the stored outputs exactly enough
    same, same_summary = golden.compute_expected(golden.bag_path(ROOT, run), params)
    assert golden.compare_series(
        run, "modelled_torque", expected["modelled_torque"], same["modelled_torque"], t
    ) is None  # fmt: skip
    assert golden.compare_summary(run, manifest["runs"][run], same_summary) == []


def test_one_moved_sample_is_located():
    t = np.arange(5) * 0.01
    exp = np.array([0.0, 100.0, 200.0, 300.0, 400.0])
    act = exp.copy()
    act[3] += 0.5
    diff = golden.compare_series("r", "modelled_torque", exp, act, t)
    assert "1 of 5 samples" in diff and "0.5 N m at sample 3 (t = 0.030 s)" in diff
    act[1] = np.nan
    assert "2 of 5 samples" in golden.compare_series("r", "modelled_torque", exp, act, t)
    assert "samples, expected" in golden.compare_series("r", "modelled_torque", exp, act[:4], t)


def test_golden_bags_decode_with_the_independent_mcap_reader():
    """zstd-compressed chunks: the mcap package (+ mcap-ros2-support) reads every message."""
    bag = golden.bag_path(ROOT, "table4_seq2")
    declared = read_columns(bag, "/rig_state")[0]
    with open(next(bag.glob("*.mcap")), "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        msgs = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/rig_state"])]
    assert len(msgs) == len(declared["stamp_ns"]) == 1400
    assert [m.actuating_pressure for m in msgs] == list(declared["actuating_pressure"])
    assert all(m.header.frame_id == "rig" and len(m.wheel_speeds) == 0 for m in msgs)
