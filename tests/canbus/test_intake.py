"""The compiled intake's pieces: columns of a batch, the fallback without numba.

Its results against the Python path are checked where both run, on the can_bridge's receive
side: ``tests/nodes/test_can_bridge_intake.py``.
"""

from __future__ import annotations

import numpy as np

from clutch_ros.canbus import intake
from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.batch import RawFrame
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.intake import CompiledIntake, columns


def test_columns_hold_the_frames() -> None:
    frames: list[RawFrame] = [(1.5, 0x100, False, False, False, False, 3, b"abc"),
                              (2.5, 0x1234, True, False, False, True, 0, b""),
                              (3.5, 0x7FF, False, True, False, False, 8, b"")]
    cols = columns(frames)
    assert cols is not None
    np.testing.assert_array_equal(cols.stamp, [1.5, 2.5, 3.5])
    np.testing.assert_array_equal(cols.ident, [0x100, 0x1234, 0x7FF])
    np.testing.assert_array_equal(cols.ext, [False, True, False])
    np.testing.assert_array_equal(cols.size, [3, 0, 0])
    np.testing.assert_array_equal(cols.offset, [0, 3, 3])
    assert cols.data[:3].tobytes() == b"abc"
    assert columns([]) is None
    assert columns([(0.0, 1 << 64, False, False, False, False, 0, b"")]) is None


def test_without_numba_the_intake_is_not_ready_and_says_why(monkeypatch) -> None:
    monkeypatch.setitem(intake._state, "scan", None)
    monkeypatch.setitem(intake._state, "reason", "numba unavailable (ImportError: test)")
    asm = RigStateAssembler(RigDatabase())
    compiled = CompiledIntake(asm, PublishPacer(100.0, None, frozenset()), (128,))
    assert not compiled.ready
    assert intake.unavailable_reason() == "numba unavailable (ImportError: test)"
    assert intake.warm_up() == "numba unavailable (ImportError: test)"
