"""clutch_ros: live torque estimation and pressure control for a wet lamella clutch.

Subpackages:
    model   pure numpy/scipy lamella-pack model (no ROS, CAN or file I/O)
    rig     the simulated rig (truth plant, pump, thermal, sensors)
    canbus  DBC codec, bus factory, frame <-> RigState assembly
    bag     rosbags typestore, recording, reading, replay
    nodes   thin rclpy adapters, one Node class per file
    cli     the ``clutch`` command

Importing this package imports nothing heavy; import the subpackages you need.
"""

__version__ = "0.1.0"
