"""Replay that estimates while it reads (clutch_ros/offline/streaming.py) against the plain one.

Real bags written with rosbags and read back: a golden run in many small pieces, a bag whose
log times are out of order (the read sorts, so the stream must be abandoned and the result
still equal), a bag through the rosbags read path (sqlite3), and a corrupt bag (the error
comes through and the worker thread stops).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from clutch_ros.bag.errors import BagError
from clutch_ros.bag.typestore import rig_state_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.offline import streaming
from clutch_ros.offline.replay import replay_bag

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden" / "bags"
FIELDS = ("accepted", "reinitialised", "modelled_torque", "reference_torque",
          "measured_torque", "torque_accuracy", "friction_coefficient", "lamella_normal_force",
          "spline_friction_force", "front_pressure", "rear_pressure", "slip_speed_filtered",
          "lamella_temperature", "compression", "spline_correction")


def _params(law="ff_t"):
    return load_params(preset_path("flexiforce_8")).with_law(law)


def _same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a.batch, name), getattr(b.batch, name),
                                      err_msg=name)  # the kernel: the very same bits
    for key in ("rmse_nm", "within_10pct", "accepted", "skipped", "samples"):
        assert a.summary[key] == b.summary[key], key


def _workers() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("clutch-estimate")]


@pytest.mark.parametrize("law", ["ff_t", "coulomb", "none"])
def test_streamed_replay_equals_the_plain_one_on_a_golden_run(law):
    bag = GOLDEN / "table3_seq2_10rpm"
    plain = replay_bag(bag, _params(law), pipeline=False)
    streamed = replay_bag(bag, _params(law), pipeline=True)
    assert streamed.summary["streamed"] and not plain.summary["streamed"]
    _same(streamed, plain)
    assert not _workers()


def test_a_bag_of_many_chunks_streams_in_pieces_with_the_same_result(tmp_path, monkeypatch):
    """Four MCAP chunks (1 MiB each), a piece per chunk; a gap and a repeated stamp inside."""
    monkeypatch.setattr(streaming, "PIECE_ROWS", 50)
    stamps = 10**18 + np.arange(15000, dtype=np.int64) * 1_000_000
    stamps[9000:] += 3_000_000_000  # a 3 s gap: the estimator re-initialises
    _write(tmp_path / "long", stamps, header_stamps={4321: stamps[4320]})
    plain = replay_bag(tmp_path / "long", _params(), pipeline=False)
    streamed = replay_bag(tmp_path / "long", _params(), pipeline=True)
    assert streamed.summary["streamed_pieces"] >= 3
    assert plain.summary["skipped"] == 1 and plain.batch.reinitialised.sum() == 2
    _same(streamed, plain)


def _write(path: Path, stamps_ns, storage="mcap", header_stamps=None):
    """Write a RigState bag; log time = header stamp except where ``header_stamps`` says."""
    rng = np.random.default_rng(3)
    with BagWriter(path, storage=storage) as writer:
        writer.add_topic("rig_state")
        for k, stamp in enumerate(stamps_ns):
            header = (header_stamps or {}).get(k, stamp)
            msg = rig_state_msg(int(header), actuating_pressure=2e5 + 1e3 * (k % 300),
                                slip_speed=1.0 + 0.01 * (k % 50), lamella_temperature=60.0,
                                measured_torque=float(rng.normal(100.0, 5.0)),
                                has_measured_torque=True)
            writer.write("rig_state", int(stamp), msg)


def test_out_of_order_log_times_abandon_the_stream_with_the_same_result(tmp_path, monkeypatch):
    monkeypatch.setattr(streaming, "PIECE_ROWS", 50)
    stamps = 10**18 + np.arange(3000, dtype=np.int64) * 1_000_000
    stamps[2000:2010] = stamps[2000:2010][::-1]  # the read sorts these by log time
    _write(tmp_path / "swapped", stamps)
    plain = replay_bag(tmp_path / "swapped", _params(), pipeline=False)
    streamed = replay_bag(tmp_path / "swapped", _params(), pipeline=True)
    assert not streamed.summary["streamed"]  # abandoned, estimated after the read
    _same(streamed, plain)
    assert plain.summary["skipped"] == 0  # sorted: every sample in order


def test_the_rosbags_read_path_streams_too(tmp_path, monkeypatch):
    monkeypatch.setattr(streaming, "PIECE_ROWS", 64)
    stamps = 10**18 + np.arange(1500, dtype=np.int64) * 1_000_000
    _write(tmp_path / "sq", stamps, storage="sqlite3")
    plain = replay_bag(tmp_path / "sq", _params(), pipeline=False)
    streamed = replay_bag(tmp_path / "sq", _params(), pipeline=True)
    assert streamed.summary["streamed"]
    _same(streamed, plain)


def test_a_corrupt_bag_raises_and_stops_the_worker(tmp_path, monkeypatch):
    monkeypatch.setattr(streaming, "PIECE_ROWS", 64)
    stamps = 10**18 + np.arange(4000, dtype=np.int64) * 1_000_000
    _write(tmp_path / "bad", stamps)
    mcap = next((tmp_path / "bad").glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    cut = len(data) * 2 // 3
    mcap.write_bytes(bytes(data[:cut]))  # truncated in the middle of the data section
    with pytest.raises(BagError):
        replay_bag(tmp_path / "bad", _params(), pipeline=True)
    assert not _workers()
