"""A ClutchEstimate bag recorded before ``modelled_torque_std`` existed still reads.

The bag is written with the older definition (the legacy typestore: the .msg files without
:data:`clutch_ros.bag.typestore.ADDED_FIELDS`), as an older clutch_ros wrote it, with its own
type hash; it is read back with the default reader, message by message and as columns.
"""

import numpy as np
import pytest

from clutch_ros import interfaces
from clutch_ros.bag.arrays import read_columns
from clutch_ros.bag.errors import UnknownTypeError
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.typestore import (
    CLUTCH_ESTIMATE_TYPE,
    clutch_typestore,
    legacy_typestore,
    make_msg,
)
from clutch_ros.bag.writer import BagWriter

TOPIC = interfaces.CLUTCH_ESTIMATE.absolute
STAMP = 1_700_000_000 * 1_000_000_000


def _write(path, store, n=5, **extra):
    with BagWriter(path, store=store) as writer:
        topic = writer.add_topic(TOPIC, CLUTCH_ESTIMATE_TYPE)
        for i in range(n):
            msg = make_msg(CLUTCH_ESTIMATE_TYPE, STAMP + i * 10_000_000, frame_id="rig",
                           store=store, modelled_torque=100.0 + i, measured_torque=99.0,
                           spline_law="ff_t", lamella_normal_force=[1.0, 2.0], **extra)
            writer.write(topic, STAMP + i * 10_000_000, msg)


def test_the_legacy_definition_differs_only_by_the_added_field():
    new, old = clutch_typestore(), legacy_typestore()
    assert new.hash_rihs01(CLUTCH_ESTIMATE_TYPE) != old.hash_rihs01(CLUTCH_ESTIMATE_TYPE)
    new_fields = [name for name, _ in new.fielddefs[CLUTCH_ESTIMATE_TYPE][1]]
    old_fields = [name for name, _ in old.fielddefs[CLUTCH_ESTIMATE_TYPE][1]]
    assert [f for f in new_fields if f != "modelled_torque_std"] == old_fields
    rig = interfaces.RIG_STATE.typename
    assert new.hash_rihs01(rig) == old.hash_rihs01(rig)


def test_an_old_bag_reads_message_by_message_and_as_columns(tmp_path):
    bag = tmp_path / "old"
    _write(bag, legacy_typestore())
    with BagReader(bag) as reader:
        msgs = [m.msg for m in reader.messages(TOPIC)]
    assert [m.modelled_torque for m in msgs] == [100.0, 101.0, 102.0, 103.0, 104.0]
    assert all(m.spline_law == "ff_t" and list(m.lamella_normal_force) == [1.0, 2.0]
               for m in msgs)
    assert not hasattr(msgs[0], "modelled_torque_std")
    cols, times, strings = read_columns(bag, TOPIC)
    assert cols["modelled_torque"].tolist() == [100.0, 101.0, 102.0, 103.0, 104.0]
    assert np.isnan(cols["modelled_torque_std"]).all() and len(times) == 5
    assert strings["spline_law"] == "ff_t"


def test_a_new_bag_carries_the_field(tmp_path):
    bag = tmp_path / "new"
    _write(bag, clutch_typestore(), modelled_torque_std=4.5)
    cols, _, _ = read_columns(bag, TOPIC)
    assert cols["modelled_torque_std"].tolist() == [4.5] * 5
    with BagReader(bag) as reader:
        assert all(m.msg.modelled_torque_std == 4.5 for m in reader.messages(TOPIC))


def test_an_explicit_store_gets_no_legacy_fallback(tmp_path):
    """Only the default reader knows the history; a given store is taken as is."""
    bag = tmp_path / "old"
    _write(bag, legacy_typestore())
    with BagReader(bag, store=clutch_typestore()) as reader:
        with pytest.raises(UnknownTypeError, match="differs from the definition"):
            list(reader.messages(TOPIC))
