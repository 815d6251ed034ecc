"""CdrCodec against rclpy's own serialisation: both ways, every field, varied alignments."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from clutch_msgs.msg import CanFrame, ClutchEstimate, RigState
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimator
from clutch_ros.nodes.convert import CdrCodec, EstimateEncoder, EstimateMessage
from clutch_ros.nodes.stamps import stamp_to_sec


def _random_message(msg_type, rng: random.Random):
    """Return a message with every leaf set: random stamps, strings of 0-9 chars, 0-9 elements."""
    msg = msg_type()
    codec = CdrCodec(msg_type)
    for name in codec.names:
        *path, leaf = name.split(".")
        owner = msg
        for part in path:
            owner = getattr(owner, part)
        current = getattr(owner, leaf)
        if isinstance(current, bool):
            value = rng.random() < 0.5
        elif isinstance(current, float):
            value = rng.choice([rng.uniform(-1e6, 1e6), math.inf, -0.0, 1e-300])
        elif isinstance(current, int):
            value = rng.randrange(0, 256 if leaf in ("dlc", "id") else 2**31)
        elif isinstance(current, str):
            value = "".join(rng.choice("abcxyz_/") for _ in range(rng.randrange(10)))
        else:  # a sequence (array('d'), numpy or list)
            n = rng.randrange(10) if not isinstance(current, np.ndarray) else len(current)
            value = [rng.uniform(-1e3, 1e3) for _ in range(n)]
        setattr(owner, leaf, value)
    return msg


def _leaf_values(msg, names) -> tuple:
    out = []
    for name in names:
        value = msg
        for part in name.split("."):
            value = getattr(value, part)
        out.append(tuple(value) if not isinstance(value, (bool, int, float, str)) else value)
    return tuple(out)


@pytest.mark.parametrize("msg_type", [RigState, ClutchEstimate, Header])
def test_decode_reads_what_rclpy_writes_and_rclpy_reads_what_encode_writes(msg_type):
    rng = random.Random(23)
    codec = CdrCodec(msg_type)
    for _ in range(200):
        msg = _random_message(msg_type, rng)
        values = _leaf_values(msg, codec.names)
        assert codec.decode(serialize_message(msg)) == values
        assert deserialize_message(codec.encode(*values), msg_type) == msg


def test_unsupported_fields_are_named():
    with pytest.raises(TypeError, match=r"CanFrame\.data: uint8\[8\] is not supported"):
        CdrCodec(CanFrame)


def test_estimate_encoder_writes_the_message_estimate_message_fills():
    """The raw ClutchEstimate equals EstimateMessage.fill's, field for field."""
    estimator = AdaptiveEstimator(load_params(preset_path("flexiforce_8")),
                                  AdaptationSettings())
    reference = EstimateMessage(ClutchEstimate)
    encoder = EstimateEncoder()
    header = Header()
    header.frame_id = "rig"
    for i in range(50):
        t = 100.0 + i * 0.001
        header.stamp.sec, header.stamp.nanosec = int(t), int(round((t % 1) * 1e9))
        res = estimator.update(t, 20e5 + 1e4 * i, 40.0, 1.0, 600.0 if i % 2 else math.nan)
        raw = encoder.encode(res.estimate, res.adaptation, header.stamp.sec,
                             header.stamp.nanosec, header.frame_id, 3.5)
        expected = reference.fill(res.estimate, res.adaptation, header, 3.5)
        got = deserialize_message(raw, ClutchEstimate)
        assert _nan_safe(got) == _nan_safe(expected)
        assert stamp_to_sec(got.header.stamp) == pytest.approx(t)


def _nan_safe(msg) -> tuple:
    codec = CdrCodec(type(msg))
    return tuple("nan" if isinstance(v, float) and math.isnan(v) else v
                 for v in _leaf_values(msg, codec.names))


def test_rig_state_encoder_writes_the_message_fill_msg_fills():
    """The can_bridge's raw rig_state equals rigstate.fill_msg's message, field for field."""
    from clutch_ros.nodes.convert import RigStateEncoder
    from clutch_ros.rigstate import RigSample, fill_msg

    rng = random.Random(5)
    encoder = RigStateEncoder()
    for i in range(100):
        sample = RigSample(
            stamp=1.7e9 + rng.uniform(0.0, 1e5), actuating_pressure=rng.uniform(0, 4e6),
            lamella_temperature=rng.choice([math.nan, 80.0]), oil_temperature=55.5,
            input_speed=rng.uniform(-50, 50), output_speed=rng.uniform(-50, 50),
            slip_speed=rng.uniform(-5, 5), measured_torque=rng.choice([math.nan, 321.0]),
            has_measured_torque=rng.random() < 0.7, torque_request=rng.uniform(0, 900),
            ff_voltages=[rng.uniform(0, 5) for _ in range(rng.choice([0, 8]))],
            wheel_speeds=[rng.uniform(0, 90) for _ in range(rng.choice([0, 4]))],
            pump_current=rng.uniform(0, 30), stale_mask=rng.randrange(2**12),
            pump_pressure=rng.uniform(0, 4e6), pump_state=rng.randrange(-1, 5),
            pump_faults=rng.randrange(256))
        stamp = sample.stamp + (0.0 if i % 2 else 12.5)  # (the bridge's clock offset)
        expected = fill_msg(RigState(), sample, stamp)
        got = deserialize_message(encoder.encode(sample, stamp), RigState)
        assert _nan_safe(got) == _nan_safe(expected)  # (rclpy leaves CDR padding unset)
