"""Bags: rosbags typestore from msg_defs, writing, reading, imports, recovery (no rclpy).

Modules:
    typestore      ``clutch_typestore()`` and message builders (``rig_state_msg`` ...)
    writer         ``BagWriter`` (MCAP default, sqlite3), QoS metadata, ``write_rig_states``
    reader         ``open_bag`` / ``BagReader``, ``check_bag``, fast ``read_rig_states``
    rig_states     ``RigStateArrays`` and the two read paths behind ``read_rig_states``
    columns        vectorized CDR -> numpy column decoding
    fastmcap       direct scan of MCAP message records (used by ``read_rig_states``)
    arrays         ``TemplateSerializer`` / ``write_columns`` (fast fixed-layout writing),
                   ``read_columns`` (any supported type as numpy columns)
    diagnose       which file is at fault; metadata.yaml vs storage comparison
    chunked        MCAP chunks closed on time, with CRC, flushed and fsync'd (crash safety)
    recover        ``recover_bag`` / ``recover_mcap``: every message of a damaged MCAP bag
                   up to the damage, and what was lost (``clutch replay --recover``)
    csv_import     ``import_csv`` (rig CSV -> RigState bag)
    channel_map    channel maps: which MDF4 channel or CSV column feeds each RigState field
    mapped_import  MDF4 (asammdf) and foreign CSV files through a channel map
    errors         ``BagError`` and its subclasses (also ``FastMcapError``,
                   ``CorruptMessageError``)

The estimator over a bag (``clutch replay``), golden data and simulated runs live in
:mod:`clutch_ros.offline`; the recorder's loss accounting in :mod:`clutch_ros.nodes`.
Importing this package imports nothing heavy; import the modules you need.
"""
