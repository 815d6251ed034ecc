"""``clutch fit`` / ``clutch calibrate`` on simulated-rig bags, and the validation report.

The bags hold the rig's truth plant (rig_truth preset, coulomb law, sensor noise) running
Table 3 at 10 rpm, written at the full 1 kHz with FlexiForce voltages. Commands are run
in-process through their ``main()`` (the same parser and error handling as ``clutch``).
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from clutch_ros.bag.writer import write_rig_states
from clutch_ros.cli import calibrate as calibrate_cmd
from clutch_ros.cli import fit as fit_cmd
from clutch_ros.config.params_file import load_flat, load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model.params import PARAMETER_SPECS, ClutchParams
from clutch_ros.model.uncertainty import DEFAULTS, ErrorModel
from clutch_ros.offline.band import fit_band
from clutch_ros.rig import RigPlant, run_offline, table3_run, table4_run

START_NS = 1_700_000_000 * 1_000_000_000


def _write(path, data, *, torque=True, voltages=True, pressure=None):
    def samples():
        for i in range(len(data["time"])):
            fields = {
                "actuating_pressure": float(data["actuating_pressure"][i]
                                            if pressure is None else pressure),
                "lamella_temperature": float(data["lamella_temperature"][i]),
                "oil_temperature": float(data["oil_temperature"][i]),
                "input_speed": float(data["input_speed"][i]), "output_speed": 0.0,
                "slip_speed": float(data["slip_speed"][i]),
                "measured_torque": float(data["measured_torque"][i]) if torque else 0.0,
                "has_measured_torque": torque,
            }
            if voltages:
                fields["ff_voltages"] = data["ff_voltages"][i].tolist()
            yield START_NS + int(round(data["time"][i] * 1e9)), fields

    write_rig_states(path, samples())
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("fit_bags")
    runs = {seq: run_offline(RigPlant(seed=seq), table3_run(seq, 10.0)) for seq in (2, 3)}
    short = {k: v[:8000] for k, v in runs[2].items()}
    return {
        "inc_step": _write(root / "inc_step", runs[2]),
        "ramp4": _write(root / "ramp4", runs[3]),
        "no_torque": _write(root / "no_torque", runs[3], torque=False),
        "constant": _write(root / "constant", short, pressure=30e5, voltages=False),
        "runs": runs,
    }


def _run(module, argv, capsys):
    argv = [str(a) for a in argv]
    if module is fit_cmd:
        argv.append("--max-seconds=0")  # no wall-time guard: results independent of load
    rc = module.main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def test_fit_writes_a_parameter_file_the_nodes_accept(bags, tmp_path, capsys):
    out_file = tmp_path / "fitted.yaml"
    rc, out, err = _run(fit_cmd, [bags["inc_step"], "--law", "coulomb", "-o", out_file,
                                  "--json"], capsys)
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["law"] == "coulomb" and doc["output"] == str(out_file)
    assert set(doc["values"]) == set(doc["stderr"]) == {
        "friction.mu_ref", "friction.temperature_slope", "friction.pressure_loss_at_ref",
        "spline.friction_coefficient", "clutch.lamella_damping"}
    assert doc["rmse"] < 1.0  # N m, at the sensor noise
    assert doc["pdiff"] is True and doc["calibration"]["method"] == "same_force"
    assert doc["calibration_comparison"]["pdiff_rms_pa"] < 0.1e5
    truth = load_params(preset_path("rig_truth")).to_flat()
    assert doc["values"]["friction.mu_ref"] == pytest.approx(truth["friction.mu_ref"],
                                                             rel=0.01)
    assert doc["values"]["spline.friction_coefficient"] == pytest.approx(0.05, rel=0.1)
    # what a node does with --params-file: the flat keys, validated, floats as doubles
    params = load_params(out_file)
    flat = load_flat(out_file)
    assert ClutchParams.from_flat(flat) == params
    assert set(PARAMETER_SPECS) <= set(flat)
    for key, spec in PARAMETER_SPECS.items():
        if spec.kind == "float":
            assert isinstance(flat[key], float), key
    assert params.spline.law == "coulomb"
    for key, value in doc["values"].items():
        assert flat[key] == pytest.approx(value)
    text = out_file.read_text()
    assert text.startswith("# clutch fit --law coulomb") and "ros__parameters" in text
    # the torque error model identified on the fit bags, written beside the parameters
    model = ErrorModel.from_flat(flat)
    assert model != DEFAULTS and model.to_flat() == pytest.approx(doc["uncertainty"])
    assert model.base > 0.0


def test_fit_prints_values_with_standard_errors(bags, tmp_path, capsys):
    out_file = tmp_path / "ff_t.yaml"
    rc, out, err = _run(fit_cmd, [bags["inc_step"], bags["ramp4"], "--law", "ff_t",
                                  "--no-pdiff", "--fix", "friction.temperature_slope",
                                  "-o", out_file], capsys)
    assert rc == 0, err
    assert "friction.mu_ref" in out and "±" in out and "fit RMSE" in out
    assert "spline.gain" in out and "[1/m]" in out and "spline.time_constant" in out
    assert "friction.temperature_slope " not in out  # fixed: kept at the base value
    assert "inc_step: RMSE" in out and "ramp4: RMSE" in out
    assert load_params(out_file).friction.temperature_slope == pytest.approx(
        load_params(preset_path("flexiforce_8")).friction.temperature_slope)


def _one_error_line(rc, out, err, *needles):
    assert rc == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("clutch fit: error:") or lines[0].startswith(
        "clutch calibrate: error:")
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert "Traceback" not in err


def test_fit_refuses_unidentifiable_data(bags, tmp_path, capsys):
    out_file = tmp_path / "never.yaml"
    _one_error_line(*_run(fit_cmd, [bags["no_torque"], "--law", "ff_v", "-o", out_file],
                          capsys), "no measured torque")
    _one_error_line(*_run(fit_cmd, [bags["constant"], "--law", "ff_t", "-o", out_file],
                          capsys), "actuating pressure is constant", "spline.gain")
    _one_error_line(*_run(fit_cmd, [tmp_path / "missing", "--law", "none", "-o", out_file],
                          capsys), "missing")
    _one_error_line(*_run(fit_cmd, [bags["inc_step"], "--law", "none", "--fix",
                                    "friction.stribeck_speed", "-o", out_file], capsys),
                    "cannot fit friction.stribeck_speed")
    _one_error_line(*_run(fit_cmd, [bags["inc_step"], "--law", "none", "--base", "nope",
                                    "-o", out_file], capsys), "no such parameter file")
    _one_error_line(*_run(fit_cmd, [bags["inc_step"], "--law", "none", "--threads", "-1",
                                    "-o", out_file], capsys), "--threads must be >= 0")
    assert not out_file.exists()


def test_fit_with_a_calibration_file(bags, tmp_path, capsys):
    """Sensors calibrated on the step run drive the P_diff of a fit on the ramp alone."""
    import yaml

    cal_file = tmp_path / "cal.yaml"
    rc, _, err = _run(calibrate_cmd, [bags["inc_step"], "-o", cal_file], capsys)
    assert rc == 0, err
    stored = yaml.safe_load(cal_file.read_text())
    out_file = tmp_path / "none.yaml"
    rc, out, err = _run(fit_cmd, [bags["ramp4"], "--law", "none", "--fix",
                                  "friction.temperature_slope", "--calibration",
                                  "same_sensor", "--calibration-file", cal_file,
                                  "-o", out_file, "--json"], capsys)  # fmt: skip
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["pdiff"] is True and doc["calibration_file"] == str(cal_file)
    assert doc["calibration"] == stored["same_sensor"]  # used as it is, not refitted
    assert doc["calibration_comparison"] is None
    rc, out, err = _run(fit_cmd, [bags["ramp4"], "--law", "none", "--fix",
                                  "friction.temperature_slope", "--calibration-file",
                                  cal_file, "-o", out_file], capsys)  # fmt: skip
    assert rc == 0, err
    assert f"P_diff from FlexiForce voltages (same_force calibration; from {cal_file})" in out
    stored["same_force"]["coefficients"] = stored["same_force"]["coefficients"][:2]
    stored["same_force"]["sensors_per_lamella"] = 1
    cal_file.write_text(yaml.safe_dump(stored))
    _one_error_line(*_run(fit_cmd, [bags["ramp4"], "--law", "none", "--calibration-file",
                                    cal_file, "-o", tmp_path / "never.yaml"], capsys),
                    "calibration is for 2 FlexiForce sensors, the bags have [8]")
    assert not (tmp_path / "never.yaml").exists()


def test_fit_runs_as_a_module(bags, tmp_path):
    out_file = tmp_path / "none.yaml"
    done = subprocess.run([sys.executable, "-m", "clutch_ros.cli.fit", str(bags["ramp4"]),
                           "--law", "none", "--fix", "friction.temperature_slope", "-o",
                           str(out_file), "--json", "--max-seconds", "0"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["law"] == "none"
    assert load_params(out_file).spline.law == "none"


def test_calibrate_compares_both_methods(bags, tmp_path, capsys):
    rc, out, err = _run(calibrate_cmd, [bags["inc_step"], "--json", "-o",
                                        tmp_path / "cal.yaml"], capsys)
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["same_force"]["method"] == "same_force"
    assert len(doc["same_sensor"]["coefficients"]) == 8
    assert doc["pdiff_correlation"] > 0.99
    assert (tmp_path / "cal.yaml").is_file()
    rc, out, err = _run(calibrate_cmd, [bags["inc_step"]], capsys)
    assert rc == 0 and "same force (Eqs. 6-9)" in out and "rear 4" in out
    _one_error_line(*_run(calibrate_cmd, [bags["constant"]], capsys), "no FlexiForce")


def test_validation_report_views(bags, tmp_path, capsys):
    from clutch_ros.model import estimate_batch
    from clutch_ros.model.identification import FitRun, evaluate
    from clutch_ros.offline.validation_report import evaluation_from_batch, write_report

    models = {}
    for law in ("none", "ff_t"):
        out_file = tmp_path / f"{law}.yaml"
        rc, _, err = _run(fit_cmd, [bags["inc_step"], "--law", law, "-o", out_file], capsys)
        assert rc == 0, err
        params = load_params(out_file)
        evals = []
        for name, data in bags["runs"].items():
            run = FitRun(data["time"], data["actuating_pressure"], data["lamella_temperature"],
                         data["slip_speed"], data["measured_torque"], name=f"seq{name}",
                         front_pressure=data["front_pressure"],
                         rear_pressure=data["rear_pressure"])
            evals.append(evaluate(params, run))
        models[law] = evals
    # a replayed bag's EstimateBatch gives the same evaluation
    data = bags["runs"][3]
    batch = estimate_batch(load_params(tmp_path / "ff_t.yaml"), data["time"],
                           data["actuating_pressure"], data["lamella_temperature"],
                           data["slip_speed"], data["measured_torque"])
    adapted = evaluation_from_batch("seq3", data["time"], batch)
    assert adapted.rmse == pytest.approx(models["ff_t"][1].rmse)
    paths, summary = write_report(models, tmp_path / "report")
    names = {p.name for p in paths}
    assert "validation_rmse.png" in names
    for kind in ("accuracy", "pdiff", "xcorr"):
        assert {f"validation_{kind}_seq2.png", f"validation_{kind}_seq3.png"} <= names
    for path in paths:
        assert path.stat().st_size > 5000 and path.read_bytes()[:4] == b"\x89PNG"
    for seq in ("seq2", "seq3"):
        for law in ("none", "ff_t"):
            cell = summary["rmse"][seq][law]
            assert cell["model"] < cell["reference"]
        assert all(0.0 <= v <= 1.0 for v in summary["xcorr_outside"][seq].values())
    assert math.isfinite(summary["rmse"]["seq3"]["ff_t"]["model"])
    assert np.isfinite(models["ff_t"][0].measured_pdiff).all()


def _hogs(count):
    """Start ``count`` busy-looping processes (a loaded machine); the caller stops them."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def test_the_same_fit_twice_writes_identical_files_even_under_load(bags, tmp_path, capsys):
    """An evaluation budget, not a wall-time limit: the load cannot change the result."""
    argv = [bags["inc_step"], "--law", "ff_t", "--no-pdiff", "--max-evaluations", "12"]
    quiet, loaded = tmp_path / "quiet.yaml", tmp_path / "loaded.yaml"
    rc, out, err = _run(fit_cmd, [*argv, "-o", quiet, "--json"], capsys)
    assert rc == 0, err
    assert json.loads(out)["evaluations"] >= 1
    hogs = _hogs(2)
    try:
        rc, _, err = _run(fit_cmd, [*argv, "-o", loaded], capsys)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    assert rc == 0, err
    assert quiet.read_bytes() == loaded.read_bytes()
    _one_error_line(*_run(fit_cmd, [*argv, "--max-evaluations", "0", "-o", tmp_path / "x"],
                          capsys), "--max-evaluations must be >= 1")


@pytest.fixture(scope="module")
def elastic_bag(tmp_path_factory):
    """Write the Test A rig's PBD run (13 lamellas, soft shafts: 1900 N m/rad)."""
    root = tmp_path_factory.mktemp("elastic")
    data = run_offline(RigPlant.from_file("rig_test_a", seed=4), table4_run(1))
    return _write(root / "pbd_test_a", data, voltages=False)


def test_fit_identifies_the_drivetrain_compliance(elastic_bag, tmp_path, capsys):
    """Standstill under pressure and the slip reversals (a stuck clutch) show the shafts."""
    out_file = tmp_path / "elastic.yaml"
    common = ["--law", "coulomb", "--base", "test_a", "--fix", "friction.temperature_slope",
              "--json"]
    rc, out, err = _run(fit_cmd, [elastic_bag, *common, "--fit-compliance", "-o", out_file],
                        capsys)
    assert rc == 0, err
    doc = json.loads(out)
    assert {"drivetrain.stiffness", "drivetrain.damping"} <= set(doc["values"])
    truth = load_params(preset_path("rig_test_a")).drivetrain
    assert doc["values"]["drivetrain.stiffness"] == pytest.approx(truth.stiffness, rel=0.1)
    assert load_params(out_file).drivetrain.stiffness == pytest.approx(
        doc["values"]["drivetrain.stiffness"])
    # without the flag the compliance stays at the base's (off); the standstill samples are
    # then left out, and with them the pressure span the pack keys need
    rigid_file = tmp_path / "rigid.yaml"
    fix = ["--fix", "friction.pressure_loss_at_ref", "--fix", "spline.friction_coefficient",
           "--fix", "clutch.lamella_damping", "--fix", "friction.film_depth", "--fix",
           "friction.film_recovery_time"]
    rc, out, err = _run(fit_cmd, [elastic_bag, *common, *fix, "-o", rigid_file], capsys)
    assert rc == 0, err
    assert "drivetrain.stiffness" not in json.loads(out)["values"]
    assert load_params(rigid_file).drivetrain.stiffness == 0.0


@pytest.mark.slow
def test_auto_fit_prints_the_validation_table(tmp_path, capsys):
    """``clutch fit --law auto --validate`` prints the validation table (issue 24).

    Golden runs (elastic rig; none used to fit): one row per passive law with its ratio (RMSE
    model / Eq. 1) on every validation run, mean and worst; no passive law worse than Eq. 1.
    """
    from tests.conftest import REPO

    bags = REPO / "tests" / "data" / "golden" / "bags"
    validate = ["table3_seq3_10rpm", "table3_seq1_30rpm", "table4_seq2"]
    rc, out, err = _run(fit_cmd, [bags / "table4_seq1", bags / "table3_seq2_10rpm", "--law",
                                  "auto", "--fit-compliance", "--no-pdiff", "--threads", "1",
                                  "-o", tmp_path / "best.yaml", "--validate",
                                  *[bags / n for n in validate]], capsys)
    assert rc == 0, err
    lines = out.splitlines()
    head = lines.index("RMSE ratio model / Eq. 1 (same friction law) per validation run:")
    rows = {}
    for line in lines[head + 1:head + 5]:
        law, _, mean, _, worst, *cells = line.split()
        ratios = dict(cell.split("=") for cell in cells)
        assert sorted(ratios) == sorted(validate), line
        ratios = {k: float(v) for k, v in ratios.items()}
        assert float(mean) == pytest.approx(np.mean(list(ratios.values())), abs=2e-3)
        assert float(worst) == pytest.approx(max(ratios.values()), abs=1e-3)
        rows[law] = ratios
    assert set(rows) == {"none", "ff_t", "ff_v", "coulomb"}
    for law, ratios in rows.items():
        assert max(ratios.values()) <= 1.0, (law, ratios)
    best = lines[head + 5].split()[1]
    assert best in rows and load_params(tmp_path / "best.yaml").drivetrain.stiffness > 0.0


def test_band_bags_widen_the_error_models_fitting_set_only(bags, tmp_path, capsys):
    """--band-bags: the error model is fitted on the fit bags and these; the law on the former."""
    plain, wide = tmp_path / "plain.yaml", tmp_path / "wide.yaml"
    argv = [bags["inc_step"], "--law", "coulomb", "--band", "fixed", "--json"]
    rc, out, err = _run(fit_cmd, [*argv, "-o", plain], capsys)
    assert rc == 0, err
    rc, out, err = _run(fit_cmd, [*argv, "-o", wide, "--band-bags", bags["ramp4"]], capsys)
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["band_bags"] == [str(bags["inc_step"]), str(bags["ramp4"])]
    assert "also fitted on " + str(bags["ramp4"]) in wide.read_text()
    # the estimator's parameters are those of the fit bags alone (the same fit, bit for bit)
    assert load_params(wide) == load_params(plain)
    # the error model is the one fitted on both runs, as clutch_ros.offline.band does it
    expected = fit_band([bags["inc_step"], bags["ramp4"]], load_params(wide), "fixed")
    got = ErrorModel.from_flat(load_flat(wide))
    np.testing.assert_allclose(list(got.to_flat().values()), list(expected.to_flat().values()),
                               rtol=1e-12)  # the same deterministic fit; the YAML round trip
    assert got != ErrorModel.from_flat(load_flat(plain))  # the ramp run moved it
