"""Fixtures of the bag-layer tests: typestore, reference messages, small bags."""

from pathlib import Path

import numpy as np
import pytest
from rosbags.interfaces import Nodetype

from clutch_ros.bag.typestore import (
    CLUTCH_ESTIMATE_TYPE,
    CLUTCH_TYPES,
    RIG_STATE_TYPE,
    clutch_typestore,
    make_msg,
)
from clutch_ros.bag.writer import BagWriter

DATA = Path(__file__).resolve().parents[1] / "data" / "csv"
STAMP_NS = 1_700_000_000_123_456_789


def reference_fields(typename: str, seed: int = 0) -> dict:
    """Distinct, non-default plain values for every field of a clutch type (header excluded)."""
    store = clutch_typestore()
    values = {}
    for index, (name, (kind, args)) in enumerate(store.fielddefs[typename][1]):
        value = seed + index
        if name == "header":
            continue
        if kind == Nodetype.BASE:
            base = args[0]
            if base == "float64":
                values[name] = value + 0.125
            elif base == "bool":
                values[name] = True
            elif base == "string":
                values[name] = f"text-{name}-{seed}"
            elif base in ("uint8", "uint32"):
                values[name] = (index * 37 + 5 + seed) % 200
            else:
                raise AssertionError(f"unhandled {base} in {typename}.{name}")
        elif kind == Nodetype.SEQUENCE:
            n = 8 if "voltages" in name else 3 + seed % 3
            values[name] = [value + 0.5 * i for i in range(n)]
        elif kind == Nodetype.ARRAY:
            values[name] = [(17 * i + 3 + seed) % 256 for i in range(args[1])]
        else:
            raise AssertionError(f"unhandled {kind} in {typename}.{name}")
    return values


def reference_msg(typename: str, seed: int = 0, frame_id: str = "clutch"):
    """Return the rosbags reference message of ``typename``."""
    return make_msg(
        typename, STAMP_NS + seed, frame_id=frame_id, **reference_fields(typename, seed)
    )


def cdr(msg, typename: str) -> bytes:
    """Serialize; equal bytes = equal messages (works with numpy array fields)."""
    return bytes(clutch_typestore().serialize_cdr(msg, typename))


@pytest.fixture(scope="session")
def store():
    return clutch_typestore()


def write_sample_bag(path: Path, storage: str = "mcap", n: int = 50) -> dict:
    """Write a bag with every clutch type; returns {topic: [(timestamp_ns, msg), ...]}."""
    topics = {
        "/rig_state": RIG_STATE_TYPE,
        "/clutch_estimate": CLUTCH_ESTIMATE_TYPE,
        "/torque_request": "clutch_msgs/msg/TorqueRequest",
        "/pressure_command": "clutch_msgs/msg/PressureCommand",
        "/can_frames": "clutch_msgs/msg/CanFrame",
    }
    assert set(topics.values()) == set(CLUTCH_TYPES)
    sent: dict = {t: [] for t in topics}
    with BagWriter(path, storage=storage) as writer:
        for topic, typename in topics.items():
            writer.add_topic(topic, typename)
        for i in range(n):
            for k, (topic, typename) in enumerate(topics.items()):
                if topic != "/rig_state" and i % (k + 1):
                    continue  # different rates per topic
                stamp = STAMP_NS + i * 1_000_000 + k
                msg = reference_msg(typename, seed=i, frame_id="f" * (i % 4))
                writer.write(topic, stamp, msg)
                sent[topic].append((stamp, msg))
    assert writer.written == {t: len(v) for t, v in sent.items()}
    return sent


@pytest.fixture
def sample_mcap(tmp_path):
    path = tmp_path / "sample_mcap"
    return path, write_sample_bag(path, "mcap")


def np_equal(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
