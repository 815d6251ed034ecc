"""The signal map: a rig's own DBC gives the same RigState values as params/rig.dbc.

Same physical values, other names, IDs, byte orders, units and scalings; bad maps fail with
one line naming the missing message or signal.

``tests/canbus/data/foreign_rig.dbc`` differs from ``params/rig.dbc`` in every message and
signal name and identifier (one 29-bit), uses Motorola byte order for two signals, kPa, kNm,
mV, mA, 1/min, rad/s, kelvin (mapped with an explicit scale and offset) and a DBC offset.
"""

import math

import pytest

from clutch_ros.canbus import PumpRequestCodec, RigDatabase, RigStateAssembler
from clutch_ros.canbus.errors import DbcError
from clutch_ros.canbus.signal_map import KEYS, SignalMap
from clutch_ros.config.params_file import load_flat
from clutch_ros.rigstate import FIELDS
from tests.conftest import REPO

DATA = REPO / "tests" / "canbus" / "data"
FOREIGN_DBC = DATA / "foreign_rig.dbc"
FOREIGN_MAP = DATA / "foreign_rig_map.yaml"
RPM = math.pi / 30.0

#: the physical values both rigs send (SI; temperatures in degC)
PHYSICAL = {"actuating_pressure": 20.5e5, "measured_torque": 456.7, "input_speed": 5.236,
            "output_speed": -0.5, "lamella_temperature": 85.25, "oil_temperature": 40.5,
            "pump_current": 7.25, "pump_pressure": 20.4e5, "pump_state": 2,
            "torque_request": 300.0, "ff": [0.5, 1.0, 1.5, 2.0, 0.1, 0.2, 0.3, 0.4],
            "wheels": [10.0, 10.5, -3.0, 0.0]}


def foreign_map() -> SignalMap:
    """Return the map of foreign_rig.dbc, read from its ROS parameter file."""
    return SignalMap({k.removeprefix("map."): v for k, v in load_flat(FOREIGN_MAP).items()})


def rig_frames(db, t):
    """params/rig.dbc frames carrying PHYSICAL at bus time ``t`` [s]."""
    p, mk = PHYSICAL, db.make_message
    return [
        mk("RigFast", {"ActuatingPressure": p["actuating_pressure"],
                       "MeasuredTorque": p["measured_torque"], "MeasuredTorqueValid": 1},
           counter=0, timestamp=t),
        mk("RigSpeed", {"InputShaftSpeed": p["input_speed"],
                        "OutputShaftSpeed": p["output_speed"]}, counter=0, timestamp=t),
        mk("RigTemperatures", {"LamellaTemperature": p["lamella_temperature"],
                               "OilTemperature": p["oil_temperature"]}, timestamp=t),
        mk("PumpStatus", {"PumpSts_State": p["pump_state"],
                          "PumpSts_ActualPressure": p["pump_pressure"],
                          "PumpSts_Current": p["pump_current"],
                          **{n: 0 for n in ("PumpSts_FltOverCurrent", "PumpSts_FltOverTemp",
                                            "PumpSts_FltUnderVoltage", "PumpSts_FltSensor",
                                            "PumpSts_FltReqTimeout", "PumpSts_FltReqChecksum",
                                            "PumpSts_FltReqCounter")}},
           counter=0, timestamp=t),
        mk("FlexiForceFront", {f"FF_Front{i + 1}": v for i, v in enumerate(p["ff"][:4])},
           timestamp=t),
        mk("FlexiForceRear", {f"FF_Rear{i + 1}": v for i, v in enumerate(p["ff"][4:])},
           timestamp=t),
        mk("WheelSpeeds", dict(zip(("WheelSpeedFL", "WheelSpeedFR", "WheelSpeedRL",
                                    "WheelSpeedRR"), p["wheels"], strict=True)), timestamp=t),
        mk("TorqueRequest", {"TorqueRequest": p["torque_request"]}, timestamp=t),
    ]


def foreign_frames(db, t):
    """Return foreign_rig.dbc frames carrying PHYSICAL at ``t`` [s].

    Values in its SI table units (Pa, N m, V, A, rad/s); the plate temperature in kelvin, a
    unit outside the table.
    """
    p, mk = PHYSICAL, db.make_message
    return [
        mk("ClutchFast", {"PistonPress": p["actuating_pressure"],
                          "FlangeTorque": p["measured_torque"], "TorqueOk": 1},
           counter=0, timestamp=t),
        mk("Shafts", {"InShaft": p["input_speed"], "OutShaft": p["output_speed"]},
           counter=0, timestamp=t),
        mk("Thermo", {"PlateTemp": p["lamella_temperature"] + 273.15,
                      "SumpTemp": p["oil_temperature"]}, timestamp=t),
        mk("HydSts", {"HydMode": p["pump_state"], "OutletPress": p["pump_pressure"],
                      "MotorCurrent": p["pump_current"]}, counter=0, timestamp=t),
        mk("PadsA", {f"PadA{i + 1}": v for i, v in enumerate(p["ff"][:4])}, timestamp=t),
        mk("PadsB", {f"PadB{i + 1}": v for i, v in enumerate(p["ff"][4:])}, timestamp=t),
        mk("Wheels", dict(zip(("WhlFL", "WhlFR", "WhlRL", "WhlRR"), p["wheels"], strict=True)),
           timestamp=t),
        mk("HostTq", {"TqDemand": p["torque_request"]}, timestamp=t),
    ]


def _tolerance(rig_db, foreign_db, rig_signal, foreign_signal) -> float:
    """Half a resolution step of each DBC (SI), the most two encodings can differ by."""
    return 0.5 * (rig_db.signal(rig_signal).resolution
                  + foreign_db.signal(foreign_signal).resolution) + 1e-9


def test_foreign_dbc_gives_the_same_rig_state_as_rig_dbc():
    rig_db = RigDatabase()
    foreign_db = RigDatabase(FOREIGN_DBC, strict_units=False)
    reference = RigStateAssembler(rig_db)
    foreign = RigStateAssembler(foreign_db, signal_map=foreign_map())
    for msg in rig_frames(rig_db, 100.0):
        assert reference.feed(msg) is not None
    for msg in foreign_frames(foreign_db, 100.0):
        assert foreign.feed(msg) is not None
    assert foreign.counters().decode_errors == 0 and foreign.counters().decoded_frames == 8
    a, b = reference.snapshot(100.0), foreign.snapshot(100.0)
    assert a.stale_mask == b.stale_mask == 0
    pairs = {"actuating_pressure": ("ActuatingPressure", "PistonPress"),
             "measured_torque": ("MeasuredTorque", "FlangeTorque"),
             "input_speed": ("InputShaftSpeed", "InShaft"),
             "output_speed": ("OutputShaftSpeed", "OutShaft"),
             "lamella_temperature": ("LamellaTemperature", "PlateTemp"),
             "oil_temperature": ("OilTemperature", "SumpTemp"),
             "pump_current": ("PumpSts_Current", "MotorCurrent"),
             "pump_pressure": ("PumpSts_ActualPressure", "OutletPress"),
             "torque_request": ("TorqueRequest", "TqDemand")}
    for field, (rig_signal, foreign_signal) in pairs.items():
        tol = _tolerance(rig_db, foreign_db, rig_signal, foreign_signal)
        assert getattr(b, field) == pytest.approx(getattr(a, field), abs=tol), field
        assert getattr(a, field) == pytest.approx(PHYSICAL[field], abs=tol), field
    assert b.slip_speed == pytest.approx(a.slip_speed, abs=2 * _tolerance(
        rig_db, foreign_db, "InputShaftSpeed", "InShaft"))
    assert a.has_measured_torque and b.has_measured_torque
    assert a.pump_state == b.pump_state == 2 and a.pump_faults == b.pump_faults == 0
    # FlexiForce: 0.1 mV both; wheels: 0.1 rpm vs 0.05 1/min
    assert b.ff_voltages == pytest.approx(a.ff_voltages, abs=1e-4 + 1e-9)
    assert b.wheel_speeds == pytest.approx(a.wheel_speeds, abs=0.075 * RPM + 1e-9)
    assert b.stamp == a.stamp == 100.0


def test_foreign_pump_request_encodes_the_same_pressure():
    foreign = foreign_map().resolve(RigDatabase(FOREIGN_DBC, strict_units=False)).pump
    reference = PumpRequestCodec()
    for pressure in (0.0, 5e5, 12.3456e5, 40e5):
        frame = foreign.encode(foreign.quantize(pressure), counter=3)
        assert frame.arbitration_id == 0x600
        decoded, counter, checksum_ok = foreign.decode(frame)
        assert checksum_ok and counter == 3
        # 0.1 kPa (100 Pa) resolution on both
        assert decoded == pytest.approx(reference.quantize(pressure), abs=100.0 + 1e-6)


def test_default_map_is_derived_from_rigstate_and_shipped_file():
    specs = SignalMap.default_specs()
    for spec in FIELDS:
        if spec.kind != "array" and spec.dbc is not None:
            assert specs[spec.name] == ".".join(spec.dbc)
    assert specs["ff_front_1"] == "FlexiForceFront.FF_Front1"
    assert specs["wheel_rr"] == "WheelSpeeds.WheelSpeedRR"
    assert specs["pump_request"] == "PumpRequest.PumpReq_Pressure"
    shipped = {k.removeprefix("map."): v
               for k, v in load_flat(REPO / "params" / "rig_signal_map.yaml").items()}
    assert shipped == specs and set(shipped) == set(KEYS)


@pytest.mark.parametrize(("changes", "words"), [
    ({"actuating_pressure": "NoSuchMessage.Pressure"}, "no message 'NoSuchMessage'"),
    ({"input_speed": "ClutchFast.Speed"}, "has no signal 'Speed'"),
    ({"lamella_temperature": "Thermo.PlateTemp"}, "unit 'K' does not convert to degC"),
    ({"oil_temperature": "Shafts.InShaft"}, "unit 'rad/s' does not convert to degC"),
    ({"pump_request": "HydCmd.PressSetpoint * 1000"}, "no '* SCALE'"),
    ({"pump_request": "HydCmd.HydCmd_Counter"}, "must be a pressure signal"),
    ({"pump_request": "ClutchFast.PistonPress"}, "ClutchFast is not E2E protected"),
])
def test_bad_foreign_map_names_the_problem(changes, words):
    specs = {**foreign_map().specs, **changes}
    key = next(iter(changes))
    with pytest.raises(DbcError) as err:
        SignalMap(specs).resolve(RigDatabase(FOREIGN_DBC, strict_units=False))
    text = str(err.value)
    assert words in text and f"map.{key}" in text and "\n" not in text


@pytest.mark.parametrize(("specs", "words"), [
    ({"input_speed": ""}, "map.input_speed is required"),
    ({"input_speed": "RigSpeed"}, "is not 'MESSAGE.SIGNAL"),
    ({"bogus": "A.B"}, "unknown key(s) bogus"),
    ({"oil_temperature": "RigTemperatures.OilTemperature + 3"}, "an offset needs a scale"),
])
def test_malformed_maps(specs, words):
    with pytest.raises(DbcError) as err:
        SignalMap(specs)
    assert words in str(err.value)


def test_default_dbc_lacking_a_mapped_signal_fails_at_resolve():
    with pytest.raises(DbcError, match="map.actuating_pressure.*no message 'ClutchFast'"):
        foreign_map().resolve(RigDatabase())
