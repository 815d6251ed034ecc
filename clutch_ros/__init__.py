"""clutch_ros: live torque estimation and pressure control for a wet lamella clutch.

Subpackages, from the bottom layer up (the import rule is in ARCHITECTURE.md):
    model      pure numpy/scipy lamella-pack model, estimator, inverse, control law,
               identification (no ROS, CAN or file I/O)
    config     ROS 2 parameter YAML files, the shipped presets, launch files (``clutch up``)
    bag        rosbags storage: typestore, writing, checked and columnar reading, imports,
               recovery of damaged MCAP files
    canbus     DBC codec, bus factory, frames <-> RigState, pump gate, CAN logs
    rig        the simulated rig (truth plant, pump, thermal, FlexiForce, scenarios, CAN port)
    offline    workflows without ROS: replay, batch jobs, fit, golden regression, reports
    dashboard  Foxglove WebSocket server of the clutch topics, bag playback (no rclpy)
    nodes      thin rclpy adapters, one Node class per file
    cli        the ``clutch`` command, one module per subcommand

Modules:
    errors       :class:`~clutch_ros.errors.ClutchError`, the one exception base
    numeric_env  numpy's native-library settings of the package's processes
    rigstate     the RigState sample: fields, units, CSV columns, DBC signals

Importing this package imports nothing heavy; import the subpackages you need.
"""

__version__ = "0.1.0"
