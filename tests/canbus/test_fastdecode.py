"""FastDecoder: the values and errors of RigDatabase.decode (cantools), bit for bit."""

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutch_ros.canbus.dbc import RigDatabase, crc8_sae_j1850
from clutch_ros.canbus.errors import FrameDecodeError
from clutch_ros.canbus.fastdecode import FastDecoder

_DB = RigDatabase()
_FAST = FastDecoder(_DB)
_KEYS = sorted(spec.key for spec in _DB.frames)


def _outcome(decode, *args):
    """(values with their types, or the error's reason, values, signals and text)."""
    try:
        values = decode(*args)
    except FrameDecodeError as err:
        return ("error", err.reason, _typed(err.values), err.signals, str(err))
    return ("ok", _typed(values))


def _typed(values):
    if values is None:
        return None
    return {k: (type(v).__name__, "nan" if isinstance(v, float) and math.isnan(v) else v)
            for k, v in values.items()}


def _same(key: int, data: bytes) -> None:
    spec = _DB.lookup(key)
    assert _outcome(_FAST.decode, key, data) == _outcome(
        _DB.decode, spec.frame_id, data, spec.is_extended)


def test_every_frame_of_the_rig_dbc_is_compiled():
    assert _FAST.compiled == frozenset(_KEYS)


@settings(max_examples=400, deadline=None)
@given(key=st.sampled_from(_KEYS), data=st.binary(min_size=8, max_size=8),
       fix_crc=st.booleans())
def test_random_payloads_decode_alike(key, data, fix_crc):
    if fix_crc and _DB.lookup(key).e2e:
        data = bytes([crc8_sae_j1850(data[1:])]) + data[1:]  # past the checksum, to the values
    _same(key, data)


@pytest.mark.parametrize("key", _KEYS)
def test_extremes_wrong_lengths_and_checksums_alike(key):
    rnd = random.Random(key)
    for data in (bytes(8), b"\xff" * 8, b"\x80" * 8, b"\x7f" * 8, bytes(7), bytes(9), b"",
                 *(rnd.randbytes(8) for _ in range(50))):
        _same(key, data)
        if len(data) == 8:
            _same(key, bytes([crc8_sae_j1850(data[1:])]) + data[1:])


def test_frames_it_cannot_compile_are_decoded_by_cantools(tmp_path):
    dbc = tmp_path / "other.dbc"
    dbc.write_text('''VERSION ""
NS_ :
BS_:
BU_: A B
BO_ 256 Motorola: 8 A
 SG_ Big : 7|16@0+ (0.5,0) [0|1000] "bar" B
BO_ 257 Floating: 8 A
 SG_ Real : 0|32@1- (1,0) [-1000|1000] "bar" B
BO_ 258 Plain: 8 A
 SG_ Count : 0|8@1+ (1,0) [0|255] "" B
 SG_ Temp : 8|16@1- (0.1,-40) [-40|200] "degC" B
SIG_VALTYPE_ 257 Real : 1;
''')
    db = RigDatabase(dbc, strict_units=False)
    fast = FastDecoder(db)
    assert fast.compiled == frozenset({258})
    rnd = random.Random(1)
    for key in (256, 257, 258):
        for _ in range(100):
            data = rnd.randbytes(8)
            assert _outcome(fast.decode, key, data) == _outcome(db.decode, key, data)


def test_a_range_error_names_every_signal_and_carries_the_values():
    key = _DB.frame("RigTemperatures").key
    raw = (-32000).to_bytes(2, "little", signed=True) * 2 + bytes(4)  # -320 degC, twice
    with pytest.raises(FrameDecodeError) as err:
        _FAST.decode(key, raw)
    assert err.value.reason == "range"
    assert err.value.signals == ("LamellaTemperature", "OilTemperature")
    assert err.value.values["LamellaTemperature"] == pytest.approx(-320.0)
