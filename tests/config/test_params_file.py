"""ROS 2 parameter YAML: load every preset, round trip, node sections, clear errors."""

import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from numpy.testing import assert_allclose

from clutch_ros.config.params_file import flatten, load_flat, load_params, nest, write_params
from clutch_ros.errors import ConfigError
from clutch_ros.model import (
    ClutchParams,
    ParameterError,
    reference_torque,
    simulate,
)

PARAMS_DIR = Path(__file__).resolve().parents[2] / "params"
PRESETS = ("flexiforce_8", "test_a_organic13", "test_b_sintered10", "rig_truth")


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_loads_and_is_plausible(name):
    params = load_params(PARAMS_DIR / f"{name}.yaml")
    assert isinstance(params, ClutchParams)
    # 40 bar at 35 degC and 10 rpm: 15 kN actuating force, 1000-1500 N m (thesis numbers)
    assert_allclose(40e5 * params.pack.piston_area, 15e3, rtol=0.01)  # "40 bar ~ 15 kN"
    torque = reference_torque(params, 40e5, 35.0, 10 * 2 * np.pi / 60)
    assert 1000.0 < torque < 1500.0
    # torque time constant c/k of the order 0.05-0.3 s (thesis 6.4.2 fits c to it)
    assert 0.05 <= params.pack.lamella_damping / params.pack.lamella_stiffness <= 0.3


@pytest.mark.parametrize("name", PRESETS)
def test_preset_files_are_plain_ros_yaml_with_typed_floats(name):
    raw = yaml.safe_load((PARAMS_DIR / f"{name}.yaml").read_text())
    assert list(raw) == ["/**"] and set(raw["/**"]) == {"ros__parameters"}
    flat = flatten(raw["/**"]["ros__parameters"])
    for key, value in flat.items():
        if key != "clutch.lamella_count" and key != "spline.law":
            assert isinstance(value, float), f"{name}: {key} must be a YAML double: {value!r}"


def test_named_presets_match_the_thesis():
    load = {n: load_params(PARAMS_DIR / f"{n}.yaml") for n in PRESETS}
    assert load["flexiforce_8"].pack.lamella_count == 8
    assert load["test_a_organic13"].pack.lamella_count == 13
    assert load["test_b_sintered10"].pack.lamella_count == 10
    ff = load["flexiforce_8"]
    assert (ff.spline.law, ff.spline.gain, ff.spline.time_constant) == ("ff_t", 0.3786, 0.9434)
    # Test B requests are capped at 1440 N m: reachable below its max pressure at 35 degC
    b = load["test_b_sintered10"]
    assert reference_torque(b, b.pack.max_pressure, 35.0, 3.14) > 1440.0


def test_rig_truth_differs_from_estimator_preset():
    est = load_params(PARAMS_DIR / "flexiforce_8.yaml")
    truth = load_params(PARAMS_DIR / "rig_truth.yaml")
    assert truth.spline.law == "coulomb" and est.spline.law != "coulomb"
    assert_allclose(truth.friction.mu_ref / est.friction.mu_ref, 1.06, rtol=1e-9)  # +6 %
    assert truth.friction.temperature_slope != est.friction.temperature_slope
    assert truth.pack.lamella_damping != est.pack.lamella_damping
    assert truth.pack.lamella_count == est.pack.lamella_count  # same rig
    t = np.arange(0.0, 2.0, 1e-3)
    a = simulate(est.with_law("none"), t, 40e5, 1.0, 35.0)
    b = simulate(truth.replace(**{"spline.law": "none"}), t, 40e5, 1.0, 35.0)
    assert abs(b.torque[-1] / a.torque[-1] - 1.0) > 0.03


def test_write_load_round_trip(tmp_path):
    params = load_params(PARAMS_DIR / "test_a_organic13.yaml").replace(
        **{"friction.mu_ref": 0.1234567890123, "clutch.lamella_damping": 3.3e7})
    path = write_params(params, tmp_path / "sub" / "out.yaml",
                        extra={"estimator.max_gap": 2.0, "rig.name": "bench 1"})
    assert load_params(path) == params
    flat = load_flat(path)
    assert flat["estimator.max_gap"] == 2.0 and flat["rig.name"] == "bench 1"
    raw = yaml.safe_load(path.read_text())
    assert isinstance(raw["/**"]["ros__parameters"]["clutch"]["lamella_damping"], float)
    assert isinstance(raw["/**"]["ros__parameters"]["friction"]["temperature_ref"], float)


def test_write_refuses_model_keys_in_extra(tmp_path):
    params = load_params(PARAMS_DIR / "flexiforce_8.yaml")
    with pytest.raises(ConfigError, match="friction.mu_ref"):
        write_params(params, tmp_path / "x.yaml", extra={"friction.mu_ref": 0.2})


def _write(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def test_node_sections_override_wildcard(tmp_path):
    base = (PARAMS_DIR / "flexiforce_8.yaml").read_text()
    path = _write(tmp_path, base + textwrap.dedent("""
        estimator:
          ros__parameters:
            friction:
              mu_ref: 0.11
            estimator:
              max_gap: 3.0
        """))
    assert load_params(path).friction.mu_ref == 0.12
    assert load_params(path, node="estimator").friction.mu_ref == 0.11
    assert load_flat(path, node="/rig1/estimator")["estimator.max_gap"] == 3.0
    assert "estimator.max_gap" not in load_flat(path)


def test_single_node_section_file(tmp_path):
    flat = load_flat(PARAMS_DIR / "flexiforce_8.yaml")
    path = _write(tmp_path, yaml.safe_dump({"estimator": {"ros__parameters": nest(flat)}}))
    assert load_params(path) == load_params(PARAMS_DIR / "flexiforce_8.yaml")


@pytest.mark.parametrize("text, match", [
    ("/**: [1, 2\n", "invalid YAML"),
    ("just a string\n", "ROS 2 parameter file"),
    ("/**:\n  parameters: {}\n", "ros__parameters"),
    ("a: {ros__parameters: {}}\nb: {ros__parameters: {}}\n", "no parameter section"),
])
def test_layout_errors_name_the_file(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as info:
        load_flat(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_params(tmp_path / "nope.yaml")


def test_bad_value_names_file_and_key(tmp_path):
    text = (PARAMS_DIR / "flexiforce_8.yaml").read_text()
    path = _write(tmp_path, text.replace("lamella_count: 8", "lamella_count: 0"))
    with pytest.raises(ParameterError) as info:
        load_params(path)
    assert info.value.key == "clutch.lamella_count"
    assert str(path) in str(info.value) and "clutch.lamella_count" in str(info.value)
    # PyYAML reads 4.0e8 (no exponent sign) as a string: caught, naming the key
    path = _write(tmp_path, text.replace("4.0e+8", "4.0e8"))
    with pytest.raises(ParameterError, match="clutch.lamella_stiffness.*expected a number"):
        load_params(path)
    path = _write(tmp_path, text.replace("    slip:\n", "    slip:\n      filter_tau: 1.0\n"))
    with pytest.raises(ParameterError, match="slip.filter_tau"):
        load_params(path)


def test_flatten_nest_inverse():
    flat = {"a.b.c": 1, "a.b.d": [1.0, 2.0], "a.e": "x", "f": 2.0}
    assert flatten(nest(flat)) == flat
    with pytest.raises(ConfigError):
        nest({"a": 1, "a.b": 2})
