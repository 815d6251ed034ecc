"""``clutch replay``: JSON summary, ClutchEstimate output, PNG report, law switch, bad inputs.

The input is a short simulated rig run (Table 3 sequence 3, 100 Hz, FlexiForce voltages)
written as a RigState bag with two bad samples injected (a NaN pressure and a repeated
stamp). The replay output is checked against the model's per-sample estimator
(``ClutchEstimator.update`` in a loop, as the live node runs it). ``--report`` writes the
replay plot and the thesis's validation views (valid PNGs, listed in the JSON summary); the
measured P_diff needs an incremented-step bag to calibrate the FlexiForce sensors on. Bad
inputs run the real command in a subprocess: one error line, exit code 2, no traceback.
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from clutch_ros.bag.arrays import read_columns
from clutch_ros.bag.reader import check_bag, open_bag
from clutch_ros.bag.typestore import torque_request_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.cli import main as clutch_main
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import TABLE7, ClutchEstimator, SampleRejected
from clutch_ros.offline.rig_runs import RigRun, simulate_run, write_run
from clutch_ros.rig.scenario import table3_run
from tests.conftest import REPO

NAN_AT, DUP_AT = 300, 500  # sample indices of the injected bad samples


@pytest.fixture(scope="module")
def run_bag(tmp_path_factory):
    """Write a RigState bag of 802 samples, 2 of them bad; return (bag, run)."""
    run = simulate_run(table3_run(3, 10.0), seed=7, rate_hz=100.0)
    stamps = list(run.stamp_ns)
    cols = {k: list(v) for k, v in run.columns.items()}
    for at, stamp in ((DUP_AT, stamps[DUP_AT - 1]), (NAN_AT, stamps[NAN_AT] - 5_000_000)):
        stamps.insert(at, stamp)  # (inserted from the back, so the indices hold)
        for k in cols:
            cols[k].insert(at, cols[k][at])
    cols["actuating_pressure"][NAN_AT] = math.nan
    bad = RigRun(run.name, np.array(stamps), {k: np.array(v) for k, v in cols.items()})
    bag = tmp_path_factory.mktemp("replay") / "seq3"
    write_run(bag, bad)
    return bag, bad


def loop_estimates(run: RigRun, params):
    """Compute what the live node does: ClutchEstimator.update per sample, rejects skipped."""
    est = ClutchEstimator(params)
    c = run.columns
    out = {}
    for i, stamp_ns in enumerate(run.stamp_ns.tolist()):
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        measured = c["measured_torque"][i] if c["has_measured_torque"][i] else math.nan
        try:
            out[stamp_ns] = est.update(sec + nsec * 1e-9, c["actuating_pressure"][i],
                                       c["lamella_temperature"][i], c["slip_speed"][i], measured)
        except SampleRejected:
            pass
    return out  # fmt: skip


def replay(capsys, *args):
    code = clutch_main(["replay", *map(str, args), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def test_json_summary_fields(run_bag, capsys):
    bag, run = run_bag
    (r,) = replay(capsys, bag, "--params", "flexiforce_8")
    for key, kind in (("bag", str), ("samples", int), ("law", str), ("rmse_nm", float),
                      ("reference_rmse_nm", float), ("within_10pct", float),
                      ("max_accuracy", float), ("min_accuracy", float)):  # fmt: skip
        assert isinstance(r[key], kind), (key, r[key])
    assert r["bag"] == str(bag) and r["law"] == "ff_t"
    assert r["samples"] == len(run) == 802 and r["accepted"] == 800 and r["skipped"] == 2
    assert 0.0 < r["within_10pct"] <= 1.0 and 0.0 < r["min_accuracy"] <= r["max_accuracy"]
    # the figures are those of the per-sample estimator
    loop = loop_estimates(run, load_params(preset_path("flexiforce_8")))
    meas = np.array([e.measured_torque for e in loop.values()])
    model = np.array([e.modelled_torque for e in loop.values()])
    ref = np.array([e.reference_torque for e in loop.values()])
    ok = np.isfinite(meas)
    assert r["rmse_nm"] == pytest.approx(np.sqrt(np.mean((meas - model)[ok] ** 2)), rel=1e-9)
    assert r["reference_rmse_nm"] == pytest.approx(np.sqrt(np.mean((meas - ref)[ok] ** 2)),
                                                   rel=1e-9)  # fmt: skip
    assert r["reference_rmse_nm"] > r["rmse_nm"] > 0.0
    # the 95 % band of modelled_torque_std (default error model), overall and per phase
    assert r["coverage_samples"] == int(ok.sum())
    assert 0 < r["coverage_transient_samples"] < r["coverage_samples"]
    for key in ("coverage_95", "coverage_95_transient", "coverage_95_steady"):
        assert 0.0 <= r[key] <= 1.0, key
    assert r["torque_std_mean_nm"] > 0.0


def test_json_coverage_uses_the_error_model_of_the_parameter_file(run_bag, capsys, tmp_path):
    """A wider error model in the parameter file covers more; a narrow one less."""
    from clutch_ros.config.params_file import write_params
    from clutch_ros.model.uncertainty import ErrorModel

    bag, _ = run_bag
    params = load_params(preset_path("flexiforce_8"))
    cover = []
    for base in (1e-3, 1e4):
        path = write_params(params, tmp_path / f"p{base}.yaml",
                            extra=ErrorModel(base=base, rel=0.0, rate_time=0.0).to_flat())
        (r,) = replay(capsys, bag, "--params", path)
        cover.append(r["coverage_95"])
        assert r["torque_std_mean_nm"] == pytest.approx(base)
    assert cover[0] < 0.5 and cover[1] == 1.0


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_output_one_estimate_per_accepted_sample_with_input_stamps(run_bag, capsys, tmp_path,
                                                                   storage):  # fmt: skip
    bag, run = run_bag
    out = tmp_path / "est"
    (r,) = replay(capsys, bag, "--params", "flexiforce_8", "-o", out, "--storage", storage)
    assert r["output"] == str(out) and r["estimates_written"] == 800
    assert check_bag(out) == {"/clutch_estimate": 800}
    cols, bag_ns, strings = read_columns(out, "clutch_estimate")
    loop = loop_estimates(run, load_params(preset_path("flexiforce_8")))
    assert cols["stamp_ns"].tolist() == list(loop) == bag_ns.tolist()
    bad = {int(run.stamp_ns[NAN_AT])}
    assert not bad & set(cols["stamp_ns"].tolist())
    assert strings == {"header.frame_id": "rig", "spline_law": "ff_t"}
    for field in ("modelled_torque", "reference_torque", "pressure_difference",
                  "friction_coefficient", "front_pressure", "rear_pressure",
                  "slip_speed_filtered", "measured_torque", "torque_accuracy"):  # fmt: skip
        want = np.array([getattr(e, field) for e in loop.values()])
        np.testing.assert_allclose(cols[field], want, rtol=1e-9, atol=1e-9, equal_nan=True,
                                   err_msg=field)  # fmt: skip
    forces = np.array([e.lamella_normal_force for e in loop.values()])
    np.testing.assert_allclose(cols["lamella_normal_force"], forces, rtol=1e-9, atol=1e-6)
    assert cols["overshoot"].tolist() == [bool(e.overshoot) for e in loop.values()]
    with open_bag(out) as b:
        (qos,) = b.topics["/clutch_estimate"].qos
        assert qos.reliability.name == "RELIABLE"


PNG = b"\x89PNG\r\n\x1a\n"
VIEWS = ("accuracy", "pdiff", "xcorr")  # per bag: Figs. 55-56, Fig. 54, Eq. 3


def _assert_png(path, min_size=5_000):
    data = open(path, "rb").read()
    assert data[:8] == PNG, path
    assert len(data) > min_size, (path, len(data))  # curves, not an empty canvas


def test_report_writes_png(run_bag, capsys, tmp_path):
    bag, _ = run_bag
    rep = tmp_path / "rep"
    (r,) = replay(capsys, bag, "--params", "flexiforce_8", "--report", rep)
    plots = r["plots"]
    assert plots[0].endswith("seq3_replay.png")
    _assert_png(plots[0], 20_000)  # four panels of curves
    # the thesis's validation views, listed in the summary and written
    want = {"validation_rmse.png"} | {f"validation_{v}_seq3.png" for v in VIEWS}
    assert {p.split("/")[-1] for p in plots[1:]} == want
    assert sorted(p.name for p in rep.iterdir()) == sorted(["seq3_replay.png", *want])
    for png in plots:
        _assert_png(png)
    val = r["validation"]
    assert set(val["xcorr_outside"]) == {"reference (Eq. 1)", "model ff_t"}
    assert all(0.0 <= x <= 1.0 for x in val["xcorr_outside"].values())
    # a ramp alone has no quasi-static samples to calibrate the FlexiForce sensors on
    assert val["measured_pdiff"] is None and "usable samples" in val["calibration_error"]
    # text mode says where the report went
    assert clutch_main(["replay", str(bag), "--params", "flexiforce_8", "--report",
                        str(tmp_path / "rep2")]) == 0  # fmt: skip
    assert f"report: 5 PNG files in {tmp_path / 'rep2'}" in capsys.readouterr().out


@pytest.fixture(scope="module")
def inc_step_bag(tmp_path_factory):
    """Write the incremented-step run (Table 3 sequence 2, 100 Hz) with FlexiForce voltages."""
    bag = tmp_path_factory.mktemp("inc") / "seq2"
    write_run(bag, simulate_run(table3_run(2, 10.0), seed=8, rate_hz=100.0))
    return bag


def test_report_measured_pdiff_from_flexiforce(run_bag, inc_step_bag, capsys, tmp_path):
    """Sensors calibrated on the replayed bags (the step run's plateaus) give P_diff."""
    bag, _ = run_bag
    rep = tmp_path / "rep"
    results = replay(capsys, bag, inc_step_bag, "--params", "flexiforce_8", "--law", "coulomb",
                     "--report", rep)  # fmt: skip
    for r, name in zip(results, ("seq3", "seq2")):
        assert r["validation"]["measured_pdiff"] == "same_force", r["validation"]
        assert r["validation"]["calibration_error"] is None
        names = {p.split("/")[-1] for p in r["plots"]}
        assert {f"{name}_replay.png", "replay_summary.png", "validation_rmse.png"} <= names
        assert {f"validation_{v}_{name}.png" for v in VIEWS} <= names
        assert set(r["validation"]["xcorr_outside"]) == {"reference (Eq. 1)", "model coulomb"}
        for png in r["plots"]:
            _assert_png(png)
    assert len(list(rep.iterdir())) == 2 + 1 + 1 + 2 * len(VIEWS)


def test_report_with_a_calibration_file(run_bag, inc_step_bag, capsys, tmp_path):
    """A lone ramp has no plateaus to calibrate on; a calibration file gives it P_diff.

    The report's P_diff RMSE is recomputed independently: the file's coefficients applied to
    the bag's voltages (accepted samples, matched by stamp) against the P_diff of the
    estimates ``-o`` wrote.
    """
    import yaml

    from clutch_ros.model.calibration import SensorCalibration

    bag, _ = run_bag
    args = ("--params", "flexiforce_8", "--law", "coulomb")
    [alone] = replay(capsys, bag, *args, "--report", tmp_path / "alone")
    assert alone["validation"]["measured_pdiff"] is None
    assert "--calibration-file" in alone["validation"]["calibration_error"]  # why, and what to do
    assert alone["validation"]["pdiff_rmse_pa"] is None
    cal_file = tmp_path / "cal.yaml"
    assert clutch_main(["calibrate", str(inc_step_bag), "-o", str(cal_file)]) == 0
    capsys.readouterr()
    est_bag = tmp_path / "est"
    [r] = replay(capsys, bag, *args, "--report", tmp_path / "rep", "--calibration",
                 "same_sensor", "--calibration-file", cal_file, "-o", est_bag)  # fmt: skip
    v = r["validation"]
    assert v["measured_pdiff"] == "same_sensor" and v["calibration_source"] == "file", v
    assert v["calibration_error"] is None

    cal = SensorCalibration.from_dict(yaml.safe_load(cal_file.read_text())["same_sensor"])
    rig, _, _ = read_columns(bag, "rig_state")
    est, _, _ = read_columns(est_bag, "clutch_estimate")
    first = {}
    for i, stamp in enumerate(rig["stamp_ns"].tolist()):
        first.setdefault(stamp, i)  # a repeated stamp is refused; its first sample counts
    rows = [first[s] for s in est["stamp_ns"].tolist()]
    area = load_params(preset_path("flexiforce_8")).pack.piston_area
    measured = cal.pressures(rig["ff_voltages"][rows], area).difference
    expected = math.sqrt(np.mean((measured - est["pressure_difference"]) ** 2))
    np.testing.assert_allclose(v["pdiff_rmse_pa"], expected, rtol=1e-9)  # same numbers
    assert 0.0 < v["pdiff_rmse_pa"] < 5e5  # a real comparison, below the 5 bar P_diff scale
    assert {f"validation_{view}_seq3.png" for view in VIEWS} <= {
        p.split("/")[-1] for p in r["plots"]}


def test_calibration_file_errors(run_bag, inc_step_bag, tmp_path):
    import yaml

    bag, _ = run_bag
    params = ("--params", "flexiforce_8", "--report", tmp_path / "rep")
    good = tmp_path / "cal.yaml"
    assert clutch_main(["calibrate", str(inc_step_bag), "-o", str(good)]) == 0
    one_error_line(clutch(bag, "--params", "flexiforce_8", "--calibration-file", good),
                   "--report")  # fmt: skip
    one_error_line(clutch(bag, *params, "--calibration-file", tmp_path / "none.yaml"),
                   "none.yaml", "cannot read calibration file")  # fmt: skip
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("same_force: [1, 2\n")
    one_error_line(clutch(bag, *params, "--calibration-file", garbage), "garbage.yaml: line 2",
                   "invalid YAML")
    doc = yaml.safe_load(good.read_text())
    doc["same_force"]["coefficients"] = doc["same_force"]["coefficients"][:4]
    doc["same_force"]["sensors_per_lamella"] = 2
    four = tmp_path / "four.yaml"
    four.write_text(yaml.safe_dump(doc))
    one_error_line(clutch(bag, *params, "--calibration-file", four),
                   "calibration is for 4 FlexiForce sensors, the bags have [8]")  # fmt: skip
    del doc["same_sensor"]
    four.write_text(yaml.safe_dump(doc))
    one_error_line(clutch(bag, *params, "--calibration", "same_sensor", "--calibration-file",
                          four), "four.yaml", "no 'same_sensor' calibration")  # fmt: skip
    assert not (tmp_path / "rep").exists() or not any((tmp_path / "rep").iterdir())


@pytest.mark.parametrize("law", ["ff_v", "ff_t", "none", "coulomb"])
def test_law_switch(run_bag, capsys, tmp_path, law):
    bag, run = run_bag
    out = tmp_path / law
    (r,) = replay(capsys, bag, "--params", "test_a", "--law", law, "-o", out)
    assert r["law"] == law
    cols, _, strings = read_columns(out, "clutch_estimate")
    assert strings["spline_law"] == law
    params = load_params(preset_path("test_a"))
    if law in ("ff_t", "ff_v"):  # Table 7's 10 rpm column
        entry = TABLE7[(law, 10)]
        params = params.replace(**{"spline.law": law, "spline.gain": entry.gain_si,
                                   "spline.time_constant": entry.time_constant})  # fmt: skip
    else:
        params = params.replace(**{"spline.law": law})
    loop = loop_estimates(run, params)
    want = np.array([e.modelled_torque for e in loop.values()])
    np.testing.assert_allclose(cols["modelled_torque"], want, rtol=1e-9, atol=1e-9)
    if law == "ff_v":  # and the law makes a difference
        (other,) = replay(capsys, bag, "--params", "test_a", "--law", "ff_t")
        assert abs(other["rmse_nm"] - r["rmse_nm"]) > 1e-3


def test_several_bags_into_a_directory(run_bag, capsys, tmp_path):
    bag, _ = run_bag
    golden = REPO / "tests" / "data" / "golden" / "bags" / "table4_seq1"
    out = tmp_path / "outs"
    results = replay(capsys, bag, golden, "--params", "flexiforce_8", "-o", out,
                     "--report", tmp_path / "rep")  # fmt: skip
    assert [r["bag"] for r in results] == [str(bag), str(golden)]
    overview = tmp_path / "rep" / "replay_summary.png"  # per-sequence reference vs model
    assert all(str(overview) in r["plots"] for r in results)
    assert overview.read_bytes()[:4] == b"\x89PNG"
    assert all(0.0 <= r["reference_within_10pct"] <= 1.0 for r in results)
    assert check_bag(out / "seq3") == {"/clutch_estimate": 800}
    assert check_bag(out / "table4_seq1") == {"/clutch_estimate": 1400}


# -- bad input: one line, exit 2, no traceback ------------------------------------------------


def clutch(*args):
    return subprocess.run(
        [sys.executable, "-m", "clutch_ros.cli", "replay", *map(str, args)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def one_error_line(proc, *parts):
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("clutch replay: error: "), proc.stderr
    for part in parts:
        assert part in lines[0], (part, lines[0])


@pytest.fixture(scope="module")
def bad_bags(run_bag, tmp_path_factory):
    bag, _ = run_bag
    root = tmp_path_factory.mktemp("bad")
    corrupt = root / "corrupt"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_bytes((bag / "metadata.yaml").read_bytes())
    data = (bag / "seq3.mcap").read_bytes()
    (corrupt / "seq3.mcap").write_bytes(data[: len(data) // 2])  # truncated mid-file
    no_rig = root / "no_rig"
    with BagWriter(no_rig) as writer:
        writer.add_topic("/torque_request")
        writer.write("/torque_request", 1_000, torque_request_msg(1_000, 50.0))
    empty = root / "empty"
    with BagWriter(empty) as writer:
        writer.add_topic("/rig_state")
    params = root / "bad_params.yaml"
    params.write_text(
        (REPO / "params" / "flexiforce_8.yaml").read_text().replace("lamella_count: 8",
                                                                    "lamella_count: -3")
    )  # fmt: skip
    return {"good": bag, "corrupt": corrupt, "no_rig": no_rig, "empty": empty, "params": params}


def test_bad_inputs_give_one_line_and_exit_2(bad_bags, tmp_path):
    good = bad_bags["good"]
    params = ("--params", "flexiforce_8")
    one_error_line(clutch(tmp_path / "missing", *params), "missing", "no such bag")
    one_error_line(clutch(bad_bags["corrupt"], *params), "corrupt")
    one_error_line(clutch(bad_bags["no_rig"], *params), "no_rig", "RigState topic, found none")
    one_error_line(clutch(bad_bags["empty"], *params), "empty", "no RigState messages")
    one_error_line(clutch(good, "--params", "no_such_preset"), "no such parameter file")
    one_error_line(clutch(good, "--params", bad_bags["params"]), "bad_params.yaml",
                   "clutch.lamella_count")  # fmt: skip
    exists = tmp_path / "exists"
    exists.mkdir()
    one_error_line(clutch(good, *params, "-o", exists), "exists already")
    assert not any(exists.iterdir())
