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
    arrays      ``TemplateSerializer`` / ``write_columns`` (fast fixed-layout writing),
                ``read_columns`` (any supported type as numpy columns)
    replay      ``replay_bag`` / ``write_estimates``: the estimator offline over a bag
                (the back end of ``clutch replay``)
    record      ``LossTracker``: exact loss counts from DDS sequence numbers (recorder)
    simrun      simulated rig runs as RigState bags (``simulate_run``, ``write_run``)
    golden      golden regression data (``tools/make_golden.py``, tests/bag/test_golden.py)
    errors      ``BagError`` and its subclasses
    bench       ``python -m benchmarks.bag_replay``: read and offline replay throughput on a
                generated one-hour 1 kHz bag

Importing this package imports nothing heavy; import the modules you need.
"""
