"""The chunked MCAP writer's fsync runs off the writer's thread (clutch_ros/bag/chunked.py).

A slow or failing disk is simulated by replacing ``os.fsync`` in the module: a real disk
whose fsync takes a second or fails with ENOSPC on demand cannot exist in a test.
"""

import errno
import threading

import numpy as np
import pytest
from mcap.reader import make_reader

from clutch_ros.bag import chunked
from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.recover import recover_mcap
from clutch_ros.bag.typestore import RIG_STATE_TYPE
from clutch_ros.bag.writer import BagWriter
from clutch_ros.errors import ClutchError

T0 = 1_700_000_000 * 10**9  # [ns]


def _write(writer, topic, i):
    ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
    write_columns(writer, topic, ser, np.array([T0 + i * 10_000_000]),
                  {"measured_torque": np.array([float(i)])})


def test_a_blocked_fsync_does_not_hold_up_writes_or_chunk_closes(tmp_path, monkeypatch):
    """While an fsync hangs, messages and whole chunks are still written (and flushed)."""
    release, started = threading.Event(), threading.Event()
    real_fsync = chunked.os.fsync

    def slow_fsync(fd):
        started.set()
        assert release.wait(30.0), "the test never released the fsync"
        real_fsync(fd)

    monkeypatch.setattr(chunked.os, "fsync", slow_fsync)
    writer = BagWriter(tmp_path / "bag", chunk_interval=1e-6, sync=True).open()
    topic = writer.add_topic("/rig_state", RIG_STATE_TYPE)
    assert started.wait(10.0)  # the open's fsync is under way, and hangs
    for i in range(20):  # a chunk per message (interval ~0): 20 chunk closes
        _write(writer, topic, i)
        assert writer.close_chunk_if_due()
    storage = writer._writer.storage
    assert storage.chunks_closed == 20
    assert storage.syncs == 0  # every one of them returned while the fsync hung
    (file,) = (tmp_path / "bag").glob("*.mcap")
    copy = tmp_path / "copy.mcap"  # flushed to the OS although not yet fsync'd: a crash
    copy.write_bytes(file.read_bytes())  # now would leave all 20 (no summary: recovered)
    rec = recover_mcap(copy)
    assert [t for _, t, _ in rec.messages] == [T0 + i * 10_000_000 for i in range(20)]
    release.set()
    writer.close()
    assert storage.syncs >= 1  # the merged requests ran after the release
    with open(file, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        assert [m.log_time for _, _, m in reader.iter_messages()] == \
            [T0 + i * 10_000_000 for i in range(20)]


def test_an_fsync_error_is_raised_by_the_next_write_with_its_cause(tmp_path, monkeypatch):
    """ENOSPC in the background fsync is not lost: the next write fails and names it."""
    failed = threading.Event()

    def full_disk(fd):
        failed.set()
        raise OSError(errno.ENOSPC, "No space left on device")

    writer = BagWriter(tmp_path / "bag", chunk_interval=1e-6, sync=True).open()
    topic = writer.add_topic("/rig_state", RIG_STATE_TYPE)
    _write(writer, topic, 0)
    syncer = writer._writer.storage._syncer
    assert syncer._idle.wait(10.0)  # the open's fsync is done (with the real fsync)
    monkeypatch.setattr(chunked.os, "fsync", full_disk)
    _write(writer, topic, 1)  # closes a chunk: its fsync fails in the background
    assert failed.wait(10.0)
    assert syncer._idle.wait(10.0)
    with pytest.raises(ClutchError, match="fsync of the chunks written before failed: No space"):
        _write(writer, topic, 2)
