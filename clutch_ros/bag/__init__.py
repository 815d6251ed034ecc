"""Bags: rosbags typestore from msg_defs, writing, reading, CSV import (no rclpy).

Modules:
    typestore   ``clutch_typestore()`` and message builders (``rig_state_msg`` ...)
    writer      ``BagWriter`` (MCAP default, sqlite3), QoS metadata, ``write_rig_states``
    reader      ``open_bag`` / ``BagReader``, ``check_bag``, fast ``read_rig_states``
    rig_states  ``RigStateArrays`` and the two read paths behind ``read_rig_states``
    columns     vectorized CDR -> numpy column decoding
    fastmcap    direct scan of MCAP message records (used by ``read_rig_states``)
    diagnose    which file is at fault; metadata.yaml vs storage comparison
    csv_import  ``import_csv`` (rig CSV -> RigState bag)
    errors      ``BagError`` and its subclasses
    bench       ``python -m clutch_ros.bag.bench``: read throughput on a generated 1 kHz bag

Importing this package imports nothing heavy; import the modules you need.
"""
