"""ClutchParams: flat <-> nested, validation naming the key, specs table, Table 7 presets."""

import dataclasses
import math

import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    PARAMETER_SPECS,
    TABLE7,
    ClutchParams,
    ParameterError,
    friction_coefficient,
)
from clutch_ros.model.params import (
    DrivetrainParams,
    FrictionParams,
    PackParams,
    SlipParams,
    SplineParams,
    ThermalParams,
)

REQUIRED = {key for key, spec in PARAMETER_SPECS.items() if spec.default is None}


def flat_base():
    return {
        "clutch.lamella_count": 8, "clutch.effective_radius": 0.045,
        "clutch.piston_area": 3.75e-3, "clutch.lamella_mass": 0.1,
        "clutch.lamella_stiffness": 4.0e8, "clutch.lamella_damping": 4.0e7,
        "friction.mu_ref": 0.12, "friction.temperature_ref": 35.0,
        "friction.temperature_slope": -0.0015, "friction.pressure_loss_at_ref": 0.05,
        "friction.pressure_ref": 4.0e6, "friction.static_ratio": 1.15,
        "friction.stribeck_speed": 0.5, "spline.law": "ff_t", "spline.gain": 0.3786,
        "spline.time_constant": 0.9434,
    }


def test_design_keys_are_exactly_the_required_ones():
    design = {"clutch.lamella_count", "clutch.effective_radius", "clutch.piston_area",
              "clutch.lamella_mass", "clutch.lamella_stiffness", "clutch.lamella_damping",
              "friction.mu_ref", "friction.temperature_ref", "friction.temperature_slope",
              "friction.pressure_loss_at_ref", "friction.pressure_ref",
              "friction.static_ratio", "friction.stribeck_speed", "spline.law",
              "spline.gain", "spline.time_constant"}
    assert REQUIRED == design


def test_specs_cover_every_field_and_defaults_are_valid():
    groups = {"clutch": PackParams, "friction": FrictionParams, "spline": SplineParams,
              "slip": SlipParams, "thermal": ThermalParams, "drivetrain": DrivetrainParams}
    keys = {f"{ns}.{f.name}" for ns, cls in groups.items() for f in dataclasses.fields(cls)}
    assert keys == set(PARAMETER_SPECS)
    for key, spec in PARAMETER_SPECS.items():
        assert spec.unit is not None and spec.description, key
        if spec.default is not None:
            assert spec.check(spec.default) == spec.default, key


def test_from_flat_to_flat_round_trip():
    params = ClutchParams.from_flat(flat_base())
    assert params.pack.lamella_count == 8 and isinstance(params.pack.lamella_count, int)
    assert params.friction.sign_speed == PARAMETER_SPECS["friction.sign_speed"].default
    flat = params.to_flat()
    assert set(flat) == set(PARAMETER_SPECS)
    assert ClutchParams.from_flat(flat) == params


def test_other_namespaces_are_ignored_but_typos_inside_rejected():
    flat = {**flat_base(), "estimator.max_gap": 1.0, "rig.noise": "x", "can.bitrate": 500000}
    ClutchParams.from_flat(flat)
    with pytest.raises(ParameterError, match=r"friction\.mu_rf.*did you mean 'friction\.mu_ref'"):
        ClutchParams.from_flat({**flat_base(), "friction.mu_rf": 0.1})


@pytest.mark.parametrize("key", sorted(REQUIRED))
def test_missing_required_key_named(key):
    flat = flat_base()
    del flat[key]
    with pytest.raises(ParameterError, match=key.replace(".", r"\.")) as info:
        ClutchParams.from_flat(flat)
    assert info.value.key == key


@pytest.mark.parametrize("key, value", [
    ("clutch.lamella_count", 0),
    ("clutch.lamella_count", -3),
    ("clutch.lamella_count", 8.5),
    ("clutch.lamella_count", True),
    ("clutch.lamella_stiffness", -4e8),
    ("clutch.lamella_stiffness", 0.0),
    ("clutch.lamella_damping", -1.0),
    ("clutch.lamella_mass", 0.0),
    ("clutch.effective_radius", math.nan),
    ("clutch.piston_area", math.inf),
    ("friction.mu_ref", -0.1),
    ("friction.mu_ref", "0.12"),
    ("friction.pressure_ref", 0.0),
    ("friction.stribeck_speed", -math.inf),
    ("spline.law", "ff_x"),
    ("spline.law", 3),
    ("spline.time_constant", 0.0),
    ("spline.gain", -1.0),
    ("slip.filter_time_constant", -0.1),
])
def test_bad_values_rejected_at_load_naming_key(key, value):
    with pytest.raises(ParameterError) as info:
        ClutchParams.from_flat({**flat_base(), key: value})
    assert info.value.key == key and key in str(info.value)


def test_cross_key_rules():
    with pytest.raises(ParameterError, match="friction.sign_speed"):
        ClutchParams.from_flat({**flat_base(), "friction.sign_speed": 0.2})  # > 0.5/5
    with pytest.raises(ParameterError, match="friction.mu_min"):
        ClutchParams.from_flat({**flat_base(), "friction.mu_min": 0.2})
    with pytest.raises(ParameterError, match="clutch.max_pressure"):
        # torque would stop growing with pressure at p_ref / (2 loss) = 4e6 / 0.2 = 2e7 Pa
        ClutchParams.from_flat({**flat_base(), "friction.pressure_loss_at_ref": 0.1,
                                "clutch.max_pressure": 2.5e7})


def test_direct_construction_is_validated_too():
    with pytest.raises(ParameterError, match="clutch.lamella_count"):
        PackParams(0, 0.045, 3.75e-3, 0.1, 4e8, 4e7)


def test_replace_and_updated(flexiforce):
    changed = flexiforce.replace(**{"friction.mu_ref": 0.13, "spline.law": "none"})
    assert changed.friction.mu_ref == 0.13 and changed.spline.law == "none"
    assert flexiforce.friction.mu_ref == 0.12  # frozen original untouched
    with pytest.raises(dataclasses.FrozenInstanceError):
        flexiforce.pack.lamella_count = 3
    with pytest.raises(ParameterError, match="clutch.lamella_count"):
        flexiforce.updated({"clutch.lamella_count": 0})
    with pytest.raises(ParameterError, match="friction.mu"):
        flexiforce.updated({"friction.mu": 0.1})


@pytest.mark.parametrize("law, rpm", sorted(TABLE7))
def test_with_law_uses_table7(flexiforce, law, rpm):
    entry = TABLE7[(law, rpm)]
    params = flexiforce.with_law(law, rpm)
    assert params.spline.law == law
    assert params.spline.time_constant == entry.time_constant
    # ff_t: kappa as printed [1/m]; ff_v: kappa 2 with dz/dt in mm/s -> 2000 s/m^2 in SI
    expected_gain = entry.kappa_thesis * (1000.0 if law == "ff_v" else 1.0)
    assert_allclose(params.spline.gain, expected_gain, rtol=0)  # exact by construction
    with pytest.raises(ParameterError, match="spline.law"):
        flexiforce.with_law(law, 50)


def test_table7_values_match_thesis():
    # Table 7 as printed: (kappa, tau) for F_f-T / F_f-V at 10 and 30 rpm
    assert (TABLE7[("ff_t", 10)].kappa_thesis, TABLE7[("ff_t", 10)].time_constant) == (
        0.3786, 0.9434)
    assert (TABLE7[("ff_v", 10)].kappa_thesis, TABLE7[("ff_v", 10)].time_constant) == (2, 2)
    assert (TABLE7[("ff_t", 30)].kappa_thesis, TABLE7[("ff_t", 30)].time_constant) == (
        0.3705, 1.9384)
    assert (TABLE7[("ff_v", 30)].kappa_thesis, TABLE7[("ff_v", 30)].time_constant) == (2, 2.5)


def test_table7_units_give_plausible_force_losses(flexiforce):
    # The unit choice (module docstring of params): at ~1230 N m, ff_t's peak force per lamella
    # kappa*T must be a few percent of the 15 kN actuating force, not ~0 and not > F_act.
    torque = 1230.0
    for rpm in (10, 30):
        peak = TABLE7[("ff_t", rpm)].gain_si * torque
        assert 0.01 * 15e3 < peak < 0.1 * 15e3
    mu = friction_coefficient(flexiforce, 35.0, 40e5, 1.047)
    assert 0.1 < mu < 0.13
